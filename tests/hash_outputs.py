"""Hash what every command writes on the samples and the shared recordings: run before and after a refactoring
that must not change any output, then compare (issue 40: "byte-identical outputs for every command").

    python -m tests.hash_outputs > after.txt       # this checkout
    git worktree add /tmp/old OLD_COMMIT; mkdir /tmp/imp; cp -r /tmp/old/evtools /tmp/imp/
    cp -r /tmp/old/cli /tmp/old/formats /tmp/imp/evtools/; cp tests/hash_outputs.py /tmp/old/tests/
    PYTHONPATH=/tmp/imp:.venv/lib/python3.11/site-packages .venv/bin/python -S /tmp/old/tests/hash_outputs.py \
        > before.txt                               # the old commit (-S: without this checkout's editable install)
    diff before.txt after.txt                      # nothing: every output is the same, byte for byte

Each line is ``sha256  command``; a command that fails prints its exit code in place of the hash (a refactoring
must not change that either). AEDAT 4.0 outputs are hashed as written (evtools writes no time of writing into
them); HDF5 files by their datasets and attributes (HDF5 stores creation times in its object headers; the scratch
folder's name is taken out of the attributes that name the input).
"""

from __future__ import annotations

import hashlib
import os
import shlex
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SAMPLES = ROOT / "samples"
SHARED = ROOT.parent / "shared" / "data"

FILTERS = ["baf", "stcf", "stcf --polarity-maps", "stcf --any-polarity --radius 2 --k 3", "dwf", "orderN",
           "refractory", "hotpixel --learn-us 200ms", "mlpf", "hotpixel,refractory,stcf", "baf --preset dv",
           "baf --preset jaer", "stcf --preset jaer", "dwf --preset jaer", "orderN --preset jaer",
           "refractory --preset jaer", "hotpixel --preset jaer", "mlpf --threshold 0.3"]


def _commands(scratch: Path) -> list[str]:
    step, flicker, texture = SAMPLES / "step.aedat4", SAMPLES / "flicker.aedat4", scratch / "texture.aedat4"
    subprocess.run([*_evtools(), "-q", "simulate", "scene:texture", "--size", "32x24", "--duration", "6s",
                    "--speed", "200", "--seed", "3", "-o", str(texture)], check=True)
    inputs = [step, flicker]
    for name in ("dvs128_walk.aedat", "davis346_lab_frames.aedat4", "gen41_sample.evt3.raw"):
        if (SHARED / name).exists():
            inputs.append(SHARED / name)
    commands = []
    for path in inputs:
        limit = "--end 2s" if path.parent == SHARED else ""
        for method in FILTERS:
            commands.append(f"bafilter {path} {limit} --method {method} -o {{out}}.aedat4")
        commands.append(f"convert {path} {limit} -o {{out}}.aedat4")
        commands.append(f"convert {path} {limit} -o {{out}}.csv")
    commands += [
        f"correct {step} --thresholds {SAMPLES / 'step.truth.h5'} -o {{out}}.aedat4",
        f"estimate {flicker} --method stimulus -o {{out}}.h5",
        f"estimate {texture} --method natural -o {{out}}.h5",
        f"estimate {step} --method offe --max-fit inf -o {{out}}.h5",
        "simulate scene:bars --size 32x24 --duration 500ms --seed 3 -o {out}.aedat4",
        # the truth files (hashed: out.h5 sorts before out.x.aedat4)
        "simulate scene:texture --size 32x24 --duration 1s --seed 3 --aps-rate 25 --aps-exposure 10ms "
        "--truth {out}.h5 -o {out}.x.aedat4",
        f"simulate {step} --shot-noise-rate-hz 5 --seed 2 --truth {{out}}.h5 -o {{out}}.x.aedat4",
    ]
    return commands


def _hash_file(path: Path, scratch: str) -> str:
    if path.suffix != ".h5":
        return hashlib.sha256(path.read_bytes()).hexdigest()
    import h5py
    import numpy as np

    digest = hashlib.sha256()
    with h5py.File(path, "r") as f:
        def visit(name, node):
            digest.update(name.encode())
            for key in sorted(node.attrs):
                value = repr(np.asarray(node.attrs[key]).tolist())  # (the input's name without the folders)
                value = value.replace(scratch, "SCRATCH").replace(str(ROOT) + "/", "")
                digest.update(key.encode() + value.encode())
            if isinstance(node, h5py.Dataset):
                digest.update(np.ascontiguousarray(node[()]).tobytes())
        visit("/", f)
        f.visititems(visit)
    return digest.hexdigest()


def _evtools() -> list[str]:
    """The command line, as the console script runs it; under ``-S`` too (an old checkout on PYTHONPATH is then
    compared without this checkout's editable install, whose finder maps ``evtools.cli`` here)."""
    return [sys.executable, *(["-S"] if sys.flags.no_site else []), "-c", "from evtools.cli import run; run()"]


def main() -> int:
    evtools = _evtools()
    with tempfile.TemporaryDirectory() as scratch:
        for index, command in enumerate(_commands(Path(scratch))):
            out = Path(scratch) / f"out{index}"
            line = command.format(out=out)
            result = subprocess.run([*evtools, "-q", *shlex.split(line)], capture_output=True, cwd=scratch,
                                    env={**os.environ, "NO_COLOR": "1"})
            written = sorted(Path(scratch).glob(f"out{index}.*"))
            shown = command.replace(scratch, "SCRATCH").replace(str(ROOT) + "/", "").replace(
                str(SHARED.parent.parent) + "/", "../")
            if result.returncode or not written:
                print(f"exit {result.returncode}  {shown}", flush=True)
            else:
                print(f"{_hash_file(written[0], scratch)}  {shown}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
