"""The package's import layers (pyproject.toml [tool.importlinter]) hold, the code is formatted and linted (ruff), and the
repository speaks of the project, not of who worked when."""

import re
import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def _lint_imports(cwd: Path) -> subprocess.CompletedProcess:
    exe = shutil.which("lint-imports") or str(Path(sys.executable).with_name("lint-imports"))
    return subprocess.run([exe, "--no-cache"], cwd=cwd, capture_output=True, text=True, timeout=300)


def test_import_contracts_are_kept():
    result = _lint_imports(ROOT)
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-2000:]
    assert "0 broken" in result.stdout


def test_a_back_import_breaks_the_contracts(tmp_path):
    """The same contracts on a copy of the package with one import up a layer (env -> train) fail."""
    shutil.copytree(ROOT / "ramavt_jax", tmp_path / "ramavt_jax", ignore=shutil.ignore_patterns("__pycache__"))
    shutil.copy(ROOT / "pyproject.toml", tmp_path / "pyproject.toml")
    env_py = tmp_path / "ramavt_jax" / "env.py"
    env_py.write_text(env_py.read_text() + "\n\ndef _back():\n    from ramavt_jax import train  # noqa\n")
    result = subprocess.run(
        [
            sys.executable,
            "-c",
            "import sys; from importlinter.cli import lint_imports_command; "
            "sys.exit(lint_imports_command(['--no-cache']))",
        ],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=300,
        env={"PYTHONPATH": str(tmp_path), "PATH": ""},
    )
    assert result.returncode != 0 and "ramavt_jax.env -> ramavt_jax.train" in result.stdout, result.stdout[-3000:]


def _ruff(*args: str) -> subprocess.CompletedProcess:
    exe = shutil.which("ruff") or str(Path(sys.executable).with_name("ruff"))
    return subprocess.run([exe, *args], cwd=ROOT, capture_output=True, text=True, timeout=120)


def test_code_is_formatted_and_linted():
    """`ruff format` and `ruff check` (settings in pyproject.toml) pass on every Python file of the repository."""
    formatted = _ruff("format", "--check", ".")
    assert formatted.returncode == 0, formatted.stdout[-3000:] + formatted.stderr[-2000:]
    linted = _ruff("check", ".")
    assert linted.returncode == 0, linted.stdout[-3000:] + linted.stderr[-2000:]


def test_every_module_has_a_layer():
    """A new top-level module must be placed in a layer, or the contracts would not see it."""
    import tomllib

    contracts = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["importlinter"]["contracts"]
    (layers,) = [c["layers"] for c in contracts if c["type"] == "layers"]
    placed = {name.strip() for layer in layers for name in layer.replace("|", ":").split(":")}
    package = ROOT / "ramavt_jax"
    present = {p.stem for p in package.glob("*.py") if p.stem not in ("__init__", "__main__")}
    present |= {p.name for p in package.iterdir() if (p / "__init__.py").is_file()}
    assert present == placed, f"not in a layer: {sorted(present - placed)}; gone: {sorted(placed - present)}"


# the two words, spelt in pieces so that this file does not match itself
_WORDS = ("sess" + "ion", "engin" + "eer")
_WHO_WORKED_WHEN = re.compile(r"\b(" + "|".join(w + "s?" for w in _WORDS) + r")\b", re.IGNORECASE)


def _text_files(root: Path) -> list[Path]:
    """The files of the repository (git's list when it is a checkout, else every file outside hidden folders)."""
    try:
        names = subprocess.run(["git", "ls-files"], cwd=root, capture_output=True, text=True, check=True).stdout
        return [root / n for n in names.splitlines() if (root / n).is_file()]
    except (OSError, subprocess.CalledProcessError):
        return [p for p in root.rglob("*") if p.is_file() and not any(x.startswith(".") for x in p.parts)]


def words_about_who_worked_when(root: Path) -> list[str]:
    """'path:line: text' for every line that names who worked when (the repository speaks of the
    project, its versions and commits)."""
    hits = []
    for path in _text_files(root):
        try:
            text = path.read_text(encoding="utf-8")
        except (UnicodeDecodeError, OSError):
            continue  # binary files (parameters, figures)
        hits += [
            f"{path.relative_to(root)}:{i}: {line.strip()[:100]}"
            for i, line in enumerate(text.splitlines(), 1)
            if _WHO_WORKED_WHEN.search(line)
        ]
    return hits


def test_the_repository_speaks_of_the_project_not_of_who_worked_when(tmp_path):
    assert words_about_who_worked_when(ROOT) == []
    line = f"measured in the fifth {_WORDS[0]}"
    (tmp_path / "notes.md").write_text(line + "\n")  # the check can fail
    assert words_about_who_worked_when(tmp_path) == [f"notes.md:1: {line}"]


def test_the_top_level_names_resolve_lazily():
    """`import ramavt_jax` imports no JAX; each curated name resolves to its module's object; others fail."""
    code = (
        "import sys, ramavt_jax as rv; assert 'jax' not in sys.modules; "
        "from ramavt_jax import env, evaluation; import ramavt_jax.evaluation.pretrained as p; "
        "assert rv.TrackingEnv is env.TrackingEnv and rv.load_pretrained is p.load; "
        "[getattr(rv, n) for n in rv.__all__]; "
        "assert sorted(rv.__all__) == sorted(set(rv.__all__)) and 'make_train' in dir(rv)\n"
        "try:\n    rv.no_such_name\nexcept AttributeError as e:\n    print(e)"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, cwd=ROOT)
    assert result.returncode == 0, result.stderr[-3000:]
    assert "no attribute 'no_such_name'" in result.stdout
