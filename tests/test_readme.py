"""README.md opens with the two commands of a fresh machine, and .ci/run calls the second."""

from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _commands() -> list[str]:
    lines = (ROOT / "README.md").read_text().splitlines()
    assert lines[0] == "```bash", "README.md must start with the two commands"
    end = lines.index("```", 1)
    return lines[1:end]


def test_readme_starts_with_two_commands():
    cmds = _commands()
    assert len(cmds) == 2
    setup, main_job = cmds[0].split(" && ")[:2], cmds[0]
    assert setup[0].startswith("python3 -m venv")
    assert "hbench reproduce" in main_job
    assert cmds[1].endswith("pytest")


def test_ci_calls_the_readme_test_command():
    ci = (ROOT / ".ci" / "run").read_text().splitlines()
    assert _commands()[1] in ci
