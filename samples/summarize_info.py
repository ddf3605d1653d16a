"""Print `evtools info --json` output (a list of files) as one compact table."""

import json
import sys

rows = json.load(sys.stdin)
rows = rows if isinstance(rows, list) else [rows]
print(f"{'file':34} {'format':8} {'sensor':>9} {'events':>10} {'span s':>8} {'ON frac':>7}")
for r in rows:
    print(f"{r['file']:34} {r['format']:8} {r['width']:>4}x{r['height']:<4} {r['events']:>10,} "
          f"{r['duration_s']:>8.3f} {r['on_fraction'] or 0:>7.3f}")
