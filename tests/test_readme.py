"""The README's promises that a newcomer relies on: its first two commands install and run the
main job, then install and run the tests; CI (.ci/run) runs that same test command; the README
stays within its 130-line budget."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _bash_blocks(text: str) -> list[str]:
    return [b.strip() for b in re.findall(r"```bash\n(.*?)```", text, flags=re.S)]


def test_first_two_commands_run_the_paper_and_the_tests_as_ci_does():
    text = (ROOT / "README.md").read_text()
    first, second = _bash_blocks(text)[:2]
    assert "pip install -e ." in first and "hlip-sweep run sweeps/paper.toml" in first
    assert (ROOT / "sweeps" / "paper.toml").is_file()
    assert "pip install -e '.[test]'" in second
    test_cmd = second.split("&&")[-1].strip()
    assert test_cmd == "python -m pytest -q"
    ci = (ROOT / ".ci" / "run").read_text()
    assert re.search(r"^python -m pytest -q$", ci, flags=re.M), "CI runs another test command"
    assert len(text.splitlines()) <= 130
