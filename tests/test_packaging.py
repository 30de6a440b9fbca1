"""The installed wheel puts only `tl_gym` into site-packages, with envs/ and agents/ inside it."""

import ast
import subprocess
import sys
import zipfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_wheel_adds_only_the_tl_gym_package(tmp_path: Path) -> None:
    subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q"]
        + ["-w", str(tmp_path), str(ROOT)],
        check=True,
        capture_output=True,
    )
    (wheel,) = tmp_path.glob("tl_gym-*.whl")
    names = zipfile.ZipFile(wheel).namelist()
    top_level = {name.split("/")[0] for name in names}
    dist_info = {t for t in top_level if t.endswith(".dist-info")}
    assert top_level - dist_info == {"tl_gym"}
    for module in ("tl_gym/tltl/parser.py", "tl_gym/envs/__init__.py", "tl_gym/agents/__init__.py",
                   "tl_gym/cli/__init__.py", "tl_gym/cli/__main__.py"):
        assert module in names
    assert not any(name.startswith(("tests/", "benchmarks/", "envs/", "agents/", "cli/")) for name in names)


def _imports(path: Path) -> set[str]:
    tree = ast.parse(path.read_text())
    found: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            found.add(node.module)
    return found


# Dependencies point one way: engine <- wrapper <- envs <- agents <- command line and benchmarks.
# (tl_gym/ reaches the envs only through Gymnasium's string entry points, which are not imports.)
ABOVE_THE_LIBRARY = ("tl_gym.envs", "tl_gym.agents", "tl_gym.cli", "benchmarks")
LAYERS = {
    "tl_gym/tltl": ("gymnasium", "stable_baselines3", "tl_gym.wrapper", "tl_gym.signals", "tl_gym.monitor_view",
                    "tl_gym.shaping", *ABOVE_THE_LIBRARY),
    "tl_gym": ABOVE_THE_LIBRARY,
    "envs": ("tl_gym.agents", "tl_gym.cli", "benchmarks"),
    "agents": ("tl_gym.cli", "benchmarks"),
    "cli": ("benchmarks",),
}


def test_dependencies_point_one_way() -> None:
    checked = 0
    for layer, forbidden in LAYERS.items():
        root = ROOT / layer
        for path in [root] if root.is_file() else sorted(root.rglob("*.py")):
            checked += 1
            bad = {m for m in _imports(path) if any(m == f or m.startswith(f + ".") for f in forbidden)}
            assert not bad, f"{path.relative_to(ROOT)} imports {sorted(bad)}, against the layering"
    assert checked >= 40
