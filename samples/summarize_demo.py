"""Print the demo's results: threshold estimation error and the uniformity of a step scene before and after
correction, from the JSON of `evtools metrics thresholds` and `evtools metrics uniformity` (paths as arguments:
THRESHOLDS.json BEFORE.json AFTER.json)."""

import json
import sys

thresholds, before, after = (json.load(open(path)) for path in sys.argv[1:4])
print(f"thresholds ({thresholds['method']}, {thresholds['valid_pixels']:,} of {thresholds['pixels']:,} pixels valid): "
      f"relative RMSE ON {100 * thresholds['on']['rel_rmse']:.2f} %, OFF {100 * thresholds['off']['rel_rmse']:.2f} %, "
      f"correlation {thresholds['on']['correlation']:.3f} / {thresholds['off']['correlation']:.3f}")
rows = [
    ("first-event std across pixels, ms", "first_std_ms", "{:.2f}"),
    ("last-event std across pixels, ms", "last_std_ms", "{:.2f}"),
    ("per-pixel event-count CV", "count_cv", "{:.3f}"),
    ("count error vs ideal sensor, events", "count_error", "{:.2f}"),
    ("timing error vs ideal sensor, ms", "timing_error_ms", "{:.2f}"),
]
print(f"\n{'step scene, mean over edges':38} {'before':>9} {'after':>9}")
for label, key, form in rows:
    print(f"{label:38} {form.format(before['summary'][key]):>9} {form.format(after['summary'][key]):>9}")
better = after["summary"]["count_error"] < before["summary"]["count_error"]
# every row is lower when nearer the ideal sensor; a change under 2 % is taken as none
changed = {label: after["summary"][key] / before["summary"][key] - 1 for label, key, _ in rows
           if before["summary"][key] > 0}
worse = [label for label, change in changed.items() if change > 0.02]
print("\ncorrection brought the stream's counts closer to the ideal sensor" if better else "\nCORRECTION DID NOT HELP")
if worse:
    print("worse after it: " + "; ".join(f"{label} ({100 * changed[label]:+.0f} %)" for label in worse))
sys.exit(0 if better else 1)
