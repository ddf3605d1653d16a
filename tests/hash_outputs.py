"""Hash what every command writes on the samples and the shared recordings: run before and after a refactoring
that must not change any output, then compare (issue 40: "byte-identical outputs for every command").

    python -m tests.hash_outputs > before.txt      # at the old commit
    python -m tests.hash_outputs > after.txt       # at the new one
    diff before.txt after.txt                      # nothing: every output is the same, byte for byte

Each line is ``sha256  command``; a command that fails prints its exit code in place of the hash (a refactoring
must not change that either). AEDAT 4.0 outputs are hashed as written (evtools writes no time of writing into
them); HDF5 files by their datasets and attributes (HDF5 stores creation times in its object headers).
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
    subprocess.run([str(_evtools()), "-q", "simulate", "scene:texture", "--size", "32x24", "--duration", "6s",
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
    ]
    return commands


def _hash_file(path: Path) -> str:
    if path.suffix != ".h5":
        return hashlib.sha256(path.read_bytes()).hexdigest()
    import h5py
    import numpy as np

    digest = hashlib.sha256()
    with h5py.File(path, "r") as f:
        def visit(name, node):
            digest.update(name.encode())
            for key in sorted(node.attrs):
                digest.update(key.encode() + repr(np.asarray(node.attrs[key]).tolist()).encode())
            if isinstance(node, h5py.Dataset):
                digest.update(np.ascontiguousarray(node[()]).tobytes())
        visit("/", f)
        f.visititems(visit)
    return digest.hexdigest()


def _evtools() -> Path:
    return Path(sys.executable).with_name("evtools")


def main() -> int:
    evtools = _evtools()
    with tempfile.TemporaryDirectory() as scratch:
        for index, command in enumerate(_commands(Path(scratch))):
            out = Path(scratch) / f"out{index}"
            line = command.format(out=out)
            result = subprocess.run([str(evtools), "-q", *shlex.split(line)], capture_output=True,
                                    env={**os.environ, "NO_COLOR": "1"})
            written = sorted(Path(scratch).glob(f"out{index}.*"))
            shown = command.replace(str(ROOT) + "/", "").replace(str(SHARED.parent.parent) + "/", "../").replace(
                scratch, "SCRATCH")
            if result.returncode or not written:
                print(f"exit {result.returncode}  {shown}", flush=True)
            else:
                print(f"{_hash_file(written[0])}  {shown}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
