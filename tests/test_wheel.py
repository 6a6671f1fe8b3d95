"""The wheel holds the package and its shipped zoo, nothing else (no tests, docs, run folders), in at most 20 MB.

Built from this checkout with pip, as a user's ``pip install`` would build it (issue 40: run folders are outputs,
not source; the zoo is the one set of weights that ships).
"""

from __future__ import annotations

import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "src" / "triplesumo"
MAX_BYTES = 20 * 1024 * 1024
SHIPPED_DATA = {".xml", ".json", ".safetensors"}
"""What the package ships besides Python: the MJCF assets and the zoo's manifests and weights."""


@pytest.fixture(scope="module")
def wheel(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("wheel")
    built = subprocess.run([sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "--no-build-isolation", "-w",
                            str(out), str(ROOT)], capture_output=True, text=True, timeout=300)
    assert built.returncode == 0, f"pip wheel failed ({built.returncode}):\n{built.stdout}\n{built.stderr}"
    (built,) = out.glob("triplesumo-*.whl")
    return built


def test_the_wheel_holds_the_package_and_the_zoo_only(wheel: Path) -> None:
    names = zipfile.ZipFile(wheel).namelist()
    tops = {n.split("/")[0] for n in names}
    assert tops == {"triplesumo", wheel.name.split("-py3")[0] + ".dist-info"}, tops
    strays = [n for n in names if n.startswith("triplesumo/") and not n.endswith("/")
              and Path(n).suffix not in {".py", *SHIPPED_DATA} and Path(n).name != "py.typed"]
    assert strays == []
    data = [n for n in names if Path(n).suffix in SHIPPED_DATA]
    assert all(n.startswith(("triplesumo/assets/", "triplesumo/agents/zoo/")) for n in data), data


def test_every_zoo_policy_and_asset_ships(wheel: Path) -> None:
    names = set(zipfile.ZipFile(wheel).namelist())
    zoo = sorted(p.relative_to(PACKAGE.parent).as_posix() for p in (PACKAGE / "agents" / "zoo").iterdir()
                 if p.suffix in {".json", ".safetensors"})
    assets = sorted(p.relative_to(PACKAGE.parent).as_posix() for p in (PACKAGE / "assets").glob("*.xml"))
    assert zoo and assets
    assert set(zoo + assets) <= names
    from triplesumo.agents.zoo import alias_target

    stems = {s for s in {Path(n).stem for n in zoo} if alias_target(s) is None}
    assert all(f"triplesumo/agents/zoo/{s}.json" in names and f"triplesumo/agents/zoo/{s}.safetensors" in names
               for s in stems)  # each policy whole: manifest and weights (an alias: its manifest, naming another)


def test_the_wheel_is_at_most_20_mb(wheel: Path) -> None:
    assert wheel.stat().st_size <= MAX_BYTES, f"{wheel.name}: {wheel.stat().st_size / 2**20:.1f} MiB"
