"""The package as a user installs it: a wheel of one top-level package, data included,
that runs the main job from any directory and lives beside Hugging Face's ``evaluate``
(which installs a top-level ``evaluate`` of its own, as our stages' old layout did)."""

from __future__ import annotations

import os
import shutil
import site as sitelib
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

pytestmark = pytest.mark.slow
ROOT = Path(__file__).resolve().parents[1]
ENV = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
"""The user's environment: nothing of the checkout on the path (only what is installed)."""


@pytest.fixture(scope="module")
def wheel(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Built from a copy of the checkout's files (the build writes its ``build/`` there)."""
    out = tmp_path_factory.mktemp("wheel")
    source = tmp_path_factory.mktemp("source")
    listed = subprocess.run(
        ["git", "ls-files", "--cached", "--others", "--exclude-standard"],
        cwd=ROOT, check=True, capture_output=True, text=True,
    ).stdout.split("\n")  # fmt: skip
    for name in filter(None, listed):
        if (ROOT / name).is_file():
            (source / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(ROOT / name, source / name)
    subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "--no-build-isolation",
         "--no-index", str(source), "-w", str(out)],
        check=True, capture_output=True, text=True,
    )  # fmt: skip
    (built,) = out.glob("care_maps-*.whl")
    return built


@pytest.fixture(scope="module")
def venv(tmp_path_factory: pytest.TempPathFactory, wheel: Path) -> Path:
    """A fresh virtual environment with the wheel installed. Its dependencies come from this
    interpreter's site-packages, put on its path by a ``.pth`` line (nothing is downloaded),
    without running that directory's own ``.pth`` files: a development install of this
    checkout there (``pip install -e``) would otherwise shadow the wheel."""
    env = tmp_path_factory.mktemp("venv") / "env"
    subprocess.run([sys.executable, "-m", "venv", str(env)], check=True)
    (site,) = (env / "lib").glob("python*/site-packages")
    (site / "dependencies.pth").write_text("\n".join(sitelib.getsitepackages()) + "\n")
    subprocess.run(
        [str(env / "bin" / "python"), "-m", "pip", "install", "-q", "--no-deps", "--no-index",
         str(wheel)],
        check=True, capture_output=True, text=True, env=ENV,
    )  # fmt: skip
    return env


def test_the_wheel_holds_one_package_and_its_data(wheel: Path) -> None:
    names = zipfile.ZipFile(wheel).namelist()
    (top,) = [n for n in names if n.endswith(".dist-info/top_level.txt")]
    assert zipfile.ZipFile(wheel).read(top).decode().split() == ["care_maps"]
    assert {n.split("/")[0] for n in names} == {"care_maps", top.split("/")[0]}
    assert "care_maps/data/sample/scene_000.mcap" in names
    assert "care_maps/data/vocabularies/scannet200.txt" in names


def test_care_run_from_an_empty_directory(venv: Path, tmp_path: Path) -> None:
    """The installed ``care`` runs the main job on the bundled sample, away from any
    checkout, from the installed package (not this repository's)."""
    here = tmp_path / "empty"
    here.mkdir()
    where = subprocess.run(
        [str(venv / "bin" / "python"), "-c", "import care_maps; print(care_maps.__file__)"],
        cwd=here, check=True, capture_output=True, text=True, env=ENV,
    ).stdout.strip()  # fmt: skip
    assert where.startswith(str(venv)), where
    done = subprocess.run(
        [str(venv / "bin" / "care"), "run", "--out", "out", "--seeds", "1"],
        cwd=here, capture_output=True, text=True, check=False, env=ENV,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-2000:]
    assert (here / "out" / "eval" / "results.md").is_file()
    assert (here / "out" / "stores" / "scene_000" / "cells.parquet").is_file()


def test_beside_hugging_faces_evaluate(venv: Path, tmp_path: Path) -> None:
    """Both import in one environment, each its own: ``evaluate`` is Hugging Face's
    (``evaluate.load``), our evaluation is ``care_maps.evaluate``."""
    pytest.importorskip("evaluate", reason="Hugging Face's evaluate: the dev extra installs it")
    code = (
        "import evaluate, care_maps.evaluate as ours; "
        "assert callable(evaluate.load), evaluate.__file__; "
        "assert callable(ours.evaluate); print(evaluate.__file__)"
    )
    done = subprocess.run(
        [str(venv / "bin" / "python"), "-c", code],
        cwd=tmp_path, capture_output=True, text=True, check=False, env=ENV,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-2000:]
    assert "care_maps" not in done.stdout
