"""Batch runs (issue 14): several inputs into a folder, a process pool or a Dask cluster, a failing file listed
while the others complete, and no input ever overwritten."""

from __future__ import annotations

import contextlib
import os
from pathlib import Path

import numpy as np
import pytest

import evtools
from tests.conftest import data_file
from tests.helpers import assert_clean_error, run, wait_until


def _recordings(folder, count=20, corrupt=None):
    folder.mkdir()
    rng = np.random.default_rng(0)
    for i in range(count):
        n = int(rng.integers(500, 3000))
        events = evtools.from_columns(np.sort(rng.integers(0, 2_000_000, n)), rng.integers(0, 64, n),
                                      rng.integers(0, 48, n), rng.integers(0, 2, n))
        evtools.write(folder / f"rec{i:02d}.aedat4", events, evtools.StreamInfo(64, 48))
    if corrupt is not None:
        (folder / corrupt).write_bytes(b"#!AER-DAT4.0\r\nthis is not a recording")
    return sorted(folder.iterdir())


def test_a_batch_gives_the_single_runs_outputs_and_lists_the_failure(tmp_path):
    files = _recordings(tmp_path / "in", corrupt="rec99.aedat4")
    result = run("bafilter", *files, "-o", tmp_path / "out", "--jobs", "2", "--method", "stcf", check=False)
    stderr = result.stderr.decode()
    assert result.returncode == 1 and "Traceback" not in stderr
    assert "rec99.aedat4" in stderr and "1 of 21 files failed" in stderr and "events in" in stderr
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == [f.name for f in files if f.name != "rec99.aedat4"]
    for file in files[:-1]:
        single = tmp_path / "single.aedat4"
        run("bafilter", file, "-o", single, "--method", "stcf")
        assert (tmp_path / "out" / file.name).read_bytes() == single.read_bytes(), file.name
        single.unlink()


def test_a_second_name_that_exists_is_never_overwritten(tmp_path):
    first, second = _recordings(tmp_path / "in", count=2)
    before = second.read_bytes()
    result = run("bafilter", first, second, check=False)
    assert result.returncode == 2 and "exists" in result.stderr.decode()
    assert second.read_bytes() == before
    # a name that does not exist yet is the output, as it always was
    run("bafilter", first, tmp_path / "new.aedat4")
    assert (tmp_path / "new.aedat4").exists()
    # three names need a folder
    result = run("bafilter", first, second, tmp_path / "x.aedat4", check=False)
    assert result.returncode == 2 and "-o FOLDER" in result.stderr.decode()


def test_convert_and_estimate_batches_name_outputs_after_inputs(tmp_path):
    files = _recordings(tmp_path / "in", count=3)
    run("convert", *files, "-o", tmp_path / "h5", "--format", "hdf5", "--jobs", "2")
    assert sorted(p.name for p in (tmp_path / "h5").iterdir()) == ["rec00.h5", "rec01.h5", "rec02.h5"]
    for file in files:
        assert np.array_equal(evtools.read(tmp_path / "h5" / (file.stem + ".h5"))[0], evtools.read(file)[0])
    run("estimate", *files, "-o", tmp_path / "maps", "--min-events", "1", "--max-fit", "inf")
    assert sorted(p.name for p in (tmp_path / "maps").iterdir()) == ["rec00.h5", "rec01.h5", "rec02.h5"]
    before = files[0].read_bytes()
    assert_clean_error(run("estimate", files[0], "-o", files[0], check=False), "overwrite the input")
    assert files[0].read_bytes() == before


def test_a_dask_cluster_gives_the_same_outputs(tmp_path):
    """--scheduler local starts a LocalCluster of --jobs single-threaded workers (dask is a test dependency)."""
    files = _recordings(tmp_path / "in", count=20)
    run("bafilter", *files, "-o", tmp_path / "pool", "--jobs", "2")
    run("bafilter", *files, "-o", tmp_path / "dask", "--jobs", "2", "--scheduler", "local")
    for file in files:
        assert (tmp_path / "dask" / file.name).read_bytes() == (tmp_path / "pool" / file.name).read_bytes()


def test_one_input_into_a_folder(tmp_path):
    """-o naming a folder (existing, or ending with /) takes one input too, named after it."""
    (first,) = _recordings(tmp_path / "in", count=1)
    (tmp_path / "maps").mkdir()
    run("estimate", first, "-o", tmp_path / "maps", "--min-events", "1", "--max-fit", "inf")
    assert [p.name for p in (tmp_path / "maps").iterdir()] == ["rec00.h5"]
    run("bafilter", first, "-o", f"{tmp_path / 'new'}/")
    assert (tmp_path / "new" / "rec00.aedat4").read_bytes() == run("bafilter", first).stdout
    result = run("bafilter", "-o", tmp_path / "maps", input=first.read_bytes(), check=False)
    assert result.returncode == 2 and "folder" in result.stderr.decode()


def test_one_inputs_output_never_replaces_another_input(tmp_path):
    """Issue 37 item 3: `ln -s a.aedat4 link.aedat4; bafilter link.aedat4 a.csv -o ./`: a.csv's output ./a.aedat4
    is the link's target, an input: a usage error before anything is written (a.aedat4 was replaced)."""
    run("simulate", "scene:bars", "--size", "16x12", "--duration", "300ms", "--seed", "1", "-o", tmp_path / "a.aedat4")
    run("convert", tmp_path / "a.aedat4", "-o", tmp_path / "a.csv")
    (tmp_path / "link.aedat4").symlink_to(tmp_path / "a.aedat4")
    original = (tmp_path / "a.aedat4").read_bytes()
    done = run("bafilter", "link.aedat4", "a.csv", "-o", "./", "--jobs", "1", check=False, cwd=tmp_path)
    assert done.returncode == 2 and "would replace the input" in done.stderr.decode(), done.stderr.decode()
    assert (tmp_path / "a.aedat4").read_bytes() == original


def test_summaries_and_json_report_each_commands_measure_of_success(tmp_path):
    """Issue 39 item 3: a batch said "ok" with "events out 0" for maps 5 % valid. Now each command reports its
    measure: estimate its valid pixels (and no events out, it writes none), bafilter the share kept, correct the
    change in events, convert whether it read its input to the end; in the table and in --json, each equal to
    what the outputs hold."""
    import json

    from evtools.formats.thresholds import read_thresholds

    files = _recordings(tmp_path / "in", count=3)
    done = run("estimate", *files, "-o", tmp_path / "maps", "--min-events", "1", "--max-fit", "inf", "--json")
    summary = json.loads(done.stdout)
    for entry in summary["files"]:
        valid = read_thresholds(str(tmp_path / "maps" / (Path(entry["input"]).stem + ".h5"))).usable()
        assert entry["valid_pixels"] == int(valid.sum()) and entry["pixels"] == valid.size == 64 * 48
        assert "events_out" not in entry and entry["events_in"] > 0
    table = run("estimate", *files, "-o", tmp_path / "maps2", "--min-events", "1", "--max-fit", "inf").stderr.decode()
    assert "pixels valid" in table and "events out" not in table
    single = json.loads(run("bafilter", files[0], "-o", tmp_path / "f.aedat4", "--json").stdout)
    kept = len(evtools.read(tmp_path / "f.aedat4")[0])
    assert single["events_out"] == kept and abs(single["kept_fraction"] - kept / single["events_in"]) < 1e-5
    table = run("bafilter", *files, "-o", tmp_path / "clean").stderr.decode()
    assert "% kept" in table and "events out" in table
    # convert stops reading past --end: what it counts is what it read, and it says so
    long = tmp_path / "long.aedat4"
    n = 600_000
    evtools.write(long, evtools.from_columns(np.arange(n) * 10, np.zeros(n), np.zeros(n), np.ones(n)),
                  evtools.StreamInfo(4, 4))
    part = run("convert", long, "-o", tmp_path / "part.aedat4", "--end", "100ms", "--json")
    counts = json.loads(part.stdout)
    assert counts["read_to_the_end"] is False and counts["events_in"] < n and counts["events_out"] == 10_000
    whole = json.loads(run("convert", long, "-o", tmp_path / "whole.aedat4", "--json").stdout)
    assert whole["read_to_the_end"] is True and whole["events_in"] == n
    said = run("convert", long, "-o", tmp_path / "part2.aedat4", "--end", "100ms").stderr.decode()
    assert "events read (reading stopped at --end)" in said


@pytest.mark.parametrize("to_group", [False, True])
def test_a_stop_ends_the_batch_where_it_is_and_says_what_each_file_got(tmp_path, to_group):
    """A QA sweep: SIGTERM to the command alone (`kill PID`, a supervisor) left its workers running every file,
    then exit 143; a terminal's Ctrl-C (the whole group) left an empty output marked cut under the final name of
    every file not yet started, and no table. Now the command forwards its signal to its workers, files not
    started get no output (`"stopped": true`), files under way end marked cut (`"cut": true`), the finished ones
    are whole; exit 128 + signal."""
    import json
    import os
    import signal
    import subprocess
    import sys

    inputs = _forty_walks(tmp_path)
    out = tmp_path / "out"
    process = subprocess.Popen([str(Path(sys.executable).parent / "evtools"), "bafilter", *inputs, "-o", str(out),
                                "--jobs", "2", "--json"],
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, start_new_session=to_group)
    try:
        wait_until(lambda: out.exists() and any(p.suffix == ".aedat4" for p in out.iterdir()), "a first output")
        if to_group:
            os.killpg(process.pid, signal.SIGINT)
        else:
            process.send_signal(signal.SIGTERM)
        stdout, stderr = process.communicate(timeout=120)
    finally:
        process.kill()
    assert process.returncode == (130 if to_group else 143), stderr
    assert b"Traceback" not in stderr
    files = json.loads(stdout)["files"]
    states = {f["input"]: "stopped" if f.get("stopped") else "cut" if f.get("cut") else "ok" for f in files}
    assert "stopped" in states.values() and "ok" in states.values(), states
    for name, state in states.items():
        output = out / Path(name).name
        assert output.exists() == (state != "stopped"), (name, state)
        if state != "stopped":
            assert json.loads(run("info", output, "--json").stdout)["cut"] == (state == "cut"), (name, state)


def test_workers_stop_with_a_command_that_was_killed(tmp_path):
    """A QA sweep: `kill -9` of the command (the OOM killer, a supervisor signalling one PID) left its workers
    running every remaining file under its final name, then waiting forever with the caller's stdout open. Now a
    worker whose command has gone stops as a stopped one does: its file ends marked cut, no file is started, and it
    exits."""
    import signal
    import subprocess
    import sys

    inputs = _forty_walks(tmp_path)
    out = tmp_path / "out"
    process = subprocess.Popen([str(Path(sys.executable).parent / "evtools"), "bafilter", *inputs, "-o", str(out),
                                "--jobs", "2"],
                               stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    try:
        wait_until(lambda: out.exists() and any(p.suffix == ".aedat4" for p in out.iterdir()), "a first output")
        workers = [int(pid) for pid in subprocess.run(["pgrep", "-P", str(process.pid)], capture_output=True,
                                                      text=True).stdout.split()]
        assert workers
        process.send_signal(signal.SIGKILL)
        process.wait(timeout=60)

        def gone(pid: int) -> bool:
            try:
                os.kill(pid, 0)
            except ProcessLookupError:
                return True
            return False

        wait_until(lambda: all(gone(pid) for pid in workers), "the workers to exit")
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(process.pid, signal.SIGKILL)
    outputs = sorted(p for p in out.iterdir() if p.suffix == ".aedat4")
    assert 0 < len(outputs) < 40 and not [p for p in out.iterdir() if p.suffix != ".aedat4"]
    for output in outputs:  # whole, or marked cut: readable either way
        run("info", output, "--json")


def _forty_walks(tmp_path) -> list[str]:
    """Forty inputs (links to the DVS128 walk repeated four times end to end: a batch that takes a while)."""
    recording, info = evtools.read(data_file("dvs128_walk.aedat"))
    span = int(recording["t"][-1] - recording["t"][0]) + 1
    source = tmp_path / "source.aedat4"
    evtools.write(source, np.concatenate([recording] + [_shifted(recording, k * span) for k in range(1, 4)]), info)
    folder = tmp_path / "in"
    folder.mkdir()
    for k in range(40):
        (folder / f"c{k:02d}.aedat4").symlink_to(source)
    return sorted(map(str, folder.iterdir()))


def _shifted(events, by_us):
    shifted = events.copy()
    shifted["t"] += by_us
    return shifted


def test_a_cut_input_is_said_in_the_json_and_the_table(tmp_path):
    """A QA sweep: a truncated input's run reported `read_to_the_end: true` and "ok", the cut said only in a
    warning. Its counts now carry `"cut": true` (single run and batch), and the table says the output is cut."""
    import json

    files = _recordings(tmp_path / "in", count=2)
    data = files[0].read_bytes()
    files[0].write_bytes(data[:len(data) * 2 // 3])  # cut inside a packet
    single = json.loads(run("-q", "bafilter", files[0], "-o", tmp_path / "one.aedat4", "--json").stdout)
    assert single["cut"] is True and single["input_cut"] is True
    whole = json.loads(run("-q", "bafilter", files[1], "-o", tmp_path / "two.aedat4", "--json").stdout)
    assert "cut" not in whole
    batch = json.loads(run("-q", "convert", *files, "-o", tmp_path / "out", "--json").stdout)
    assert [f.get("cut", False) for f in batch["files"]] == [True, False]
    table = run("bafilter", *files, "-o", tmp_path / "out2").stderr.decode()
    assert "input cut: output cut" in table


def test_a_batch_folder_named_like_a_recording_is_a_usage_error(tmp_path):
    """QA sweeps: `-o merged.aedat4` with several inputs silently made a folder of that name, then did so with a
    warning and exit 0 (a script that meant one file got a folder). It is now a usage error (exit 2, nothing made)
    unless the name ends with / (a folder asked for) or the folder exists."""
    files = _recordings(tmp_path / "in", count=2)
    result = run("bafilter", *files, "-o", tmp_path / "merged.aedat4", check=False)
    assert result.returncode == 2 and "this names a recording" in result.stderr.decode()
    assert not (tmp_path / "merged.aedat4").exists()
    run("bafilter", *files, "-o", f"{tmp_path / 'merged.aedat4'}/")
    assert (tmp_path / "merged.aedat4").is_dir()
    again = run("bafilter", *files, "-o", tmp_path / "merged.aedat4")  # (an existing folder: nothing to say)
    assert again.returncode == 0 and len(list((tmp_path / "merged.aedat4").iterdir())) == 2


def _dying_one(input, output, **options):
    """A command's one-file work whose worker dies at rec01 (picklable: module level)."""
    from evtools.cli.batch import Outcome

    if input.endswith("rec01.aedat4"):
        os._exit(9)
    return Outcome(1, 1)


def test_a_worker_that_dies_is_a_failed_file_not_a_traceback(tmp_path):
    """A worker killed (out of memory, a signal the pool cannot survive) broke the pool, and the batch ended in a
    traceback. Its files are listed as failed (the pool's other files may fail with it), exit 1."""
    from evtools.cli.batch import BatchError, run as run_batch

    files = _recordings(tmp_path / "in", count=3)
    with pytest.raises(BatchError) as failed:
        run_batch(_dying_one, [(str(f), str(tmp_path / f.name)) for f in files], {}, jobs=2)
    assert "rec01.aedat4" in str(failed.value) and "files failed" in str(failed.value)
