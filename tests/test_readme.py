"""Every code block of the README runs (issue 18 item 4): each in an empty folder of its own, with only the
repository's ``samples/`` beside it (as ``samples``) and the environment's ``evtools`` first on the PATH. A block
makes the files it reads in its own earlier lines. A block that cannot run here says why in an HTML comment on the
line before it (``<!-- not run: REASON -->``), which the README shows to nobody; there are few, and each names its
reason. The set-up block's ``make demo`` runs in the repository (its ``.venv`` exists: ``make test`` made it), and
its ``make test`` is this suite."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
NOT_RUN = re.compile(r"<!-- not run: (.+?) -->")


def blocks() -> list[tuple[int, str, str, str | None]]:
    """(first line number, language, code, reason it is not run or None) of every fenced block."""
    lines = README.read_text().splitlines()
    found, i = [], 0
    while i < len(lines):
        fence = re.match(r"^```(\w*)\s*$", lines[i])
        if not fence:
            i += 1
            continue
        end = next(j for j in range(i + 1, len(lines)) if lines[j].startswith("```"))
        reason = NOT_RUN.search(lines[i - 1]) if i else None
        found.append((i + 1, fence.group(1), "\n".join(lines[i + 1:end]) + "\n", reason and reason.group(1)))
        i = end + 1
    return found


def test_the_readme_has_blocks_and_few_are_not_run():
    found = blocks()
    assert len(found) >= 15 and all(language in ("sh", "python") for _, language, _, _ in found)
    skipped = [(line, reason) for line, _, _, reason in found if reason]
    assert len(skipped) <= 2, skipped
    assert all(len(reason) > 20 for _, reason in skipped)


RUNNABLE = [block for block in blocks() if not block[3]]


@pytest.mark.parametrize("line,language,code,reason", RUNNABLE, ids=[f"line{block[0]}" for block in RUNNABLE])
def test_a_readme_block_runs(tmp_path, line, language, code, reason):
    if code.startswith("make demo"):  # the set-up block: `make test` is what runs this test
        assert "make test" in code
        code = "make demo\n"
        tmp_path = ROOT
    if tmp_path != ROOT:
        (tmp_path / "samples").symlink_to(ROOT / "samples")
    environment = {**os.environ, "PATH": f"{Path(sys.executable).parent}{os.pathsep}{os.environ['PATH']}",
                   "HOME": str(tmp_path)}
    argv = ["bash", "-e", "-o", "pipefail", "-c", code] if language == "sh" else [sys.executable, "-c", code]
    run = subprocess.run(argv, cwd=tmp_path, env=environment, capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, f"README line {line}: exit {run.returncode}\n{run.stderr[-3000:]}"
    assert "Traceback" not in run.stderr, f"README line {line}:\n{run.stderr[-3000:]}"
