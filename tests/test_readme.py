"""The README stays a quickstart that is true: short, and its Python and command-line blocks run as written on the
bundled samples (commands on ../shared data run when it is present)."""
import os
import pathlib
import re
import shlex

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text()


def _blocks(lang: str) -> list:
    return re.findall(rf"```{lang}\n(.*?)```", README, flags=re.S)


def test_readme_is_a_quickstart():
    lines = README.splitlines()
    assert len(lines) <= 200
    assert lines[3:5] == ["make demo   # fresh machine, Python 3.11 only: installs the runtime (no torch) into "
                          ".venv-demo and runs the bundled sample",
                          "make test   # creates .venv, installs torch==2.13.0 (CPU) then equipose[train,camera,dev], "
                          "runs pytest"]
    for target in re.findall(r"\]\(([^)#]+)\)", README):                       # every linked page exists
        assert (ROOT / target).exists(), target


def test_readme_python_runs(capsys):
    (code,) = _blocks("python")
    exec(compile(code, "README.md", "exec"), {})
    assert "mug R(rotvec°)=" in capsys.readouterr().out


def _cli_lines() -> list:
    out = []
    for block in _blocks("bash"):
        for line in block.splitlines():
            line = line.split("  #")[0].strip()
            if line.startswith("equipose "):
                out.append(line)
    return out


@pytest.mark.parametrize("line", _cli_lines())
def test_readme_command_runs(line, tmp_path, monkeypatch):
    from equipose.cli import main
    args = shlex.split(line)[1:]
    shared = [a for a in args if a.startswith("../shared/")]
    if any(not (ROOT / a).exists() for a in shared):
        pytest.skip(f"needs {shared[0]}")
    monkeypatch.chdir(ROOT)
    if "-o" in args:                                                            # outputs into a fresh folder
        args[args.index("-o") + 1] = str(tmp_path / "out")
    os.environ.setdefault("DEPTHAI_LEVEL", "error")
    assert main(args) == 0
