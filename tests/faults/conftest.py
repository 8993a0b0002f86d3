"""The fault-injection suite's inputs and checks.

Inputs are made with the real writers: a sample-world recording (MCAP through ``mcap``, with
ground truth) rendered once per session at 64x48 and 4 frames, bags through ``rosbags``;
faults are real: truncated and altered files, ``RLIMIT_FSIZE`` (the kernel refuses writes
past the limit: a full disk as a process sees it), ``SIGKILL`` mid-run, ``chmod`` (run
without the DAC-override capability when the tests run as root, so permissions bind).

Each fault asserts the five properties of ``FaultCheck``: the exit code, a single line on
stderr, no traceback, nothing half-written (no temporary left) and earlier good output
intact; and then that a re-run succeeds.
"""

from __future__ import annotations

import contextlib
import ctypes
import hashlib
import json
import os
import re
import resource
import shutil
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PROGRESS = re.compile(r"\d+%\|.*\| *[\d?]+/[\d?]+ \[|^[\w ]+: \d+it \[\d\d:\d\d, ")
"""A tqdm bar's frame: with a total (``40%|####  | 2/5 [``), or without (``scenes: 0it [00:00, ``)."""
BAR_FRAME = re.compile(r"^.*?\d+%\|[^|]*\| *[\d?]+/[\d?]+ \[[^\]]*\]")
"""A whole tqdm frame at the start of a line: a worker's bar, left unfinished when the run
was stopped, and the program's line written after it."""
CURSOR = re.compile(r"\x1b\[[0-9;]*[A-Za-z]")
"""A terminal control sequence (tqdm moves the cursor up over nested bars): not text."""
TMP_NAME = re.compile(r"^\..+\.(tmp|old|building)-\d+")


def _env() -> dict[str, str]:
    env = dict(os.environ)
    env["TQDM_DISABLE"] = "1"
    env["PYTHONPATH"] = str(ROOT) + os.pathsep + env.get("PYTHONPATH", "")
    env.setdefault("OMP_NUM_THREADS", "1")
    return env


def _drop_dac() -> None:
    """Without CAP_DAC_OVERRIDE / CAP_DAC_READ_SEARCH, so chmod binds even for root."""
    libc = ctypes.CDLL(None, use_errno=True)
    for cap in (1, 2):  # CAP_DAC_OVERRIDE, CAP_DAC_READ_SEARCH
        libc.prctl(24, cap, 0, 0, 0)  # PR_CAPBSET_DROP; EPERM when not root: nothing to drop


def care_process(
    *args: object, fsize: int | None = None, timeout: float = 300
) -> subprocess.CompletedProcess[str]:
    """Run ``care ARGS`` in a fresh process (optionally under an ``RLIMIT_FSIZE``)."""

    def preexec() -> None:
        _drop_dac()
        if fsize is not None:  # Python ignores SIGXFSZ: writes past it fail with EFBIG
            resource.setrlimit(resource.RLIMIT_FSIZE, (fsize, fsize))

    return subprocess.run(
        [sys.executable, "-m", "care_maps.cli.main", *map(str, args)],
        cwd=ROOT,
        env=_env(),
        capture_output=True,
        text=True,
        timeout=timeout,
        preexec_fn=preexec,
        check=False,
    )


def _as_a_terminal_job() -> None:
    """The child as a job a terminal or a scheduler started: SIGHUP and SIGTERM at their
    default, whatever the test runner inherited (under ``nohup`` SIGHUP is ignored, and the
    program rightly keeps ignoring it), and without CAP_DAC_* (:func:`_drop_dac`)."""
    for signum in (signal.SIGHUP, signal.SIGTERM):
        signal.signal(signum, signal.SIG_DFL)
    _drop_dac()


def care_popen(*args: object) -> subprocess.Popen[str]:
    return subprocess.Popen(
        [sys.executable, "-m", "care_maps.cli.main", *map(str, args)],
        cwd=ROOT,
        env=_env(),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=_as_a_terminal_job,
    )


WAIT_S = 120.0
"""How long a test waits for a state it signals at: generous, for a loaded CI machine."""


def wait_for(
    proc: subprocess.Popen[str], seen: Callable[[], object], timeout: float = WAIT_S
) -> bool:
    """Poll until ``seen()`` is true while ``proc`` runs: whether it was (False: ``proc``
    ended first). A fault test signals at a state it can see (a temporary appearing, a module
    loaded), never after a fixed delay, which a busy machine stretches past any margin."""
    deadline = time.monotonic() + timeout
    while proc.poll() is None and time.monotonic() < deadline:
        try:
            if seen():
                return proc.poll() is None
        except OSError:  # a path that vanished while looked at
            pass
        time.sleep(0.002)
    assert time.monotonic() < deadline, f"not seen within {timeout} s"
    return False


def loading(proc: subprocess.Popen[str]) -> Callable[[], bool]:
    """The program is loading its modules: numpy's compiled core is mapped (the first big
    import, past the interpreter's own start-up)."""
    maps = Path(f"/proc/{proc.pid}/maps")
    return lambda: "_multiarray_umath" in maps.read_text()


def appears(folder: Path, pattern: str) -> Callable[[], bool]:
    """A path matching ``pattern`` exists in ``folder`` (a temporary, a lock, a table)."""
    return lambda: any(Path(folder).glob(pattern))


def children(pid: int) -> set[int]:
    """The processes whose parent is ``pid`` (its workers, multiprocessing's resource
    tracker)."""
    found = set()
    for stat in Path("/proc").glob("[0-9]*/stat"):
        with contextlib.suppress(OSError, ValueError, IndexError):
            if int(stat.read_text().rsplit(")", 1)[1].split()[1]) == pid:
                found.add(int(stat.parent.name))
    return found


def alive(pid: int) -> bool:
    """Whether ``pid`` runs (a zombie is not running)."""
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (OSError, IndexError):
        return False
    return state != "Z"


@pytest.fixture
def care(run_cli: Callable, monkeypatch: pytest.MonkeyPatch) -> Callable:
    """Run ``care ARGS`` in this process (fast): ``(exit code, stdout, stderr)``, without
    progress bars (tests/conftest.py's ``run_cli``)."""
    monkeypatch.setenv("TQDM_DISABLE", "1")
    return run_cli


def snapshot(*roots: Path) -> dict[str, str]:
    """Every file (hidden ones too) under ``roots``: relative path -> content hash."""
    files: dict[str, str] = {}
    for root in roots:
        root = Path(root)
        if root.is_file():
            files[str(root)] = hashlib.sha256(root.read_bytes()).hexdigest()
            continue
        for p in sorted(root.rglob("*")):
            if p.is_file() and not p.name.endswith(".lock"):
                files[str(p)] = hashlib.sha256(p.read_bytes()).hexdigest()
    return files


def leftovers(*dirs: Path) -> list[Path]:
    """Temporaries (``.<name>.tmp-<pid>`` etc.) and lock files in and below ``dirs``."""
    return [
        p
        for d in map(Path, dirs)
        if d.is_dir()
        for p in d.rglob(".*")
        if TMP_NAME.match(p.name) or p.name.endswith(".lock")
    ]


def assert_fault(
    code: int,
    err: str,
    pattern: str,
    *,
    exit_code: int = 1,
    clean: tuple[Path, ...] = (),
    intact: dict[str, str] | None = None,
) -> str:
    """The five properties: exit code, one line on stderr (matching ``pattern``), no traceback,
    no temporary left in ``clean``, and the files of ``intact`` unchanged."""
    assert code == exit_code, (code, err)
    assert "Traceback" not in err, err
    # what a terminal shows: a progress bar redraws with \r, a finished one clears itself
    # (in a pipe, tqdm may leave a bar's last frame: a bar, not a line of text)
    lines = [
        seen
        for line in err.split("\n")
        if (seen := BAR_FRAME.sub("", CURSOR.sub("", line.rsplit("\r", 1)[-1])).strip())
        and not PROGRESS.search(seen)
    ]
    assert len(lines) == 1, err
    assert lines[0].startswith("error: "), lines[0]
    assert re.search(pattern, lines[0]), lines[0]
    assert not leftovers(*clean), leftovers(*clean)
    if intact is not None:
        roots = {Path(p) for p in intact}
        now = {k: v for k, v in snapshot(*roots).items() if k in intact}
        assert now == intact
    return lines[0]


def tables(store: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(Path(store).glob("*.parquet"))}


@pytest.fixture(scope="session")
def world(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A sample-world dataset (1 scene, 4 frames, 64x48) with ground truth, rendered once."""
    from care_maps.world.record import DatasetConfig, make_dataset

    root = tmp_path_factory.mktemp("faults_world")
    make_dataset(
        DatasetConfig(
            out=root / "ds", scenes=1, seed=3, fmt="mcap", width=64, height=48, frames=4,
            num_rooms=1, workers=1,
        )
    )  # fmt: skip
    return root / "ds"


@pytest.fixture(scope="session")
def recording(world: Path) -> Path:
    return world / "scene_000.mcap"


@pytest.fixture(scope="session")
def good(tmp_path_factory: pytest.TempPathFactory, recording: Path) -> Path:
    """A store with both maps and an evaluation beside it, built once (read-only)."""
    from care_maps.evaluate.job import run_eval
    from care_maps.fuse.grid import GridConfig, build_grid
    from care_maps.fuse.instances import InstanceConfig, build_instances
    from care_maps.ingest.pipeline import IngestConfig, run_ingest
    from care_maps.runtime.execution import Execution

    root = tmp_path_factory.mktemp("faults_good")
    run = Execution(workers=1, progress=False)
    store = run_ingest(recording, root / "store", IngestConfig(encoder="labels"), run=run)
    build_grid(store, GridConfig(cell_size=0.1), run=run)
    build_instances(store, InstanceConfig(proposals="labels"), run=run)
    run_eval(store, eval_config(), root / "eval", run=run)
    return root


EVAL_FLAGS = ("--seeds", "2", "--bootstrap", "10", "--workers", "1", "--k-grid", "4,8",
              "--k-instances", "2,4")  # fmt: skip


def eval_config():
    from care_maps.evaluate.job import EvalConfig

    return EvalConfig(seeds=2, bootstrap=10, k_grid=(4, 8), k_instances=(2, 4))


@pytest.fixture
def copy_good(good: Path, tmp_path: Path) -> Callable[[str], Path]:
    """A private copy of part of the good outputs (``store`` or ``eval``)."""

    def copy(name: str) -> Path:
        dst = tmp_path / name
        shutil.copytree(good / name, dst)
        return dst

    return copy


@contextlib.contextmanager
def chmod(path: Path, mode: int) -> Iterator[None]:
    old = Path(path).stat().st_mode & 0o7777
    Path(path).chmod(mode)
    try:
        yield
    finally:
        Path(path).chmod(old)


def meta(store: Path) -> dict:
    return json.loads((Path(store) / "meta.json").read_text())


# -- hand-built rosbag2 recordings (rosbags' Writer), for faults our writer never makes ----


def write_bag(
    path: Path,
    *,
    n: int = 3,
    w: int = 32,
    h: int = 24,
    quat: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 1.0),
    xyz: tuple[float, float, float] = (0.0, 0.0, 1.0),
    tf_edges: tuple[tuple[str, str], ...] = (("map", "camera_optical_frame"),),
    rgb_bytes_delta: int = 0,
    stamps: list[int] | None = None,
    shades: list[int] | None = None,
    dynamic: tuple[tuple[int, str, str, tuple[float, ...], tuple[float, ...]], ...] = (),
    colour: Callable | None = None,
) -> Path:
    """A small RGB-D rosbag2 (mcap storage): ``tf_edges`` on /tf_static (the last one gets
    ``quat``/``xyz``), rgb8 colour with ``rgb_bytes_delta`` bytes more (or fewer) than
    w x h x 3, 16UC1 depth, camera info; colour stamps ``stamps`` (default 100 ms apart),
    image i all grey level ``shades[i]`` (default 40 i); ``dynamic`` transforms
    ``(stamp, parent, child, xyz, quat)`` on /tf, one message each, logged at their stamp;
    ``colour(types, stamp, header)``, if given, makes each colour message instead (a
    CompressedImage, an empty Image, ...)."""
    import numpy as np
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    T = ts.types

    def header(t: int, frame: str = "camera_optical_frame"):
        stamp = T["builtin_interfaces/msg/Time"](sec=t // 10**9, nanosec=t % 10**9)
        return T["std_msgs/msg/Header"](stamp=stamp, frame_id=frame)

    def image(t: int, data: np.ndarray, enc: str, step: int, nbytes: int):
        flat = np.ascontiguousarray(data).view(np.uint8).reshape(-1)
        if nbytes > flat.size:
            flat = np.concatenate([flat, np.zeros(nbytes - flat.size, np.uint8)])
        return T["sensor_msgs/msg/Image"](
            header=header(t), height=h, width=w, encoding=enc, is_bigendian=0, step=step,
            data=flat[:nbytes],
        )  # fmt: skip

    def tf(t: int, parent: str, child: str, q, p):
        tr = T["geometry_msgs/msg/Transform"](
            translation=T["geometry_msgs/msg/Vector3"](x=p[0], y=p[1], z=p[2]),
            rotation=T["geometry_msgs/msg/Quaternion"](x=q[0], y=q[1], z=q[2], w=q[3]),
        )
        st = T["geometry_msgs/msg/TransformStamped"](
            header=header(t, parent), child_frame_id=child, transform=tr
        )
        return T["tf2_msgs/msg/TFMessage"](transforms=[st])

    K = np.array([40.0, 0, w / 2, 0, 40.0, h / 2, 0, 0, 1])
    roi = T["sensor_msgs/msg/RegionOfInterest"](
        x_offset=0, y_offset=0, height=0, width=0, do_rectify=False
    )
    info = T["sensor_msgs/msg/CameraInfo"](
        header=header(10**9), height=h, width=w, distortion_model="plumb_bob", d=np.zeros(5),
        k=K, r=np.eye(3).ravel(), p=np.c_[K.reshape(3, 3), np.zeros(3)].ravel(),
        binning_x=0, binning_y=0, roi=roi,
    )  # fmt: skip
    messages: list[tuple[str, int, object]] = []
    for i, (parent, child) in enumerate(tf_edges):
        last = i == len(tf_edges) - 1
        messages.append(
            ("/tf_static", 10**9, tf(10**9, parent, child, quat if last else (0, 0, 0, 1),
                                     xyz if last else (0, 0, 0)))
        )  # fmt: skip
    for t, parent, child, p, q in dynamic:
        messages.append(("/tf", t, tf(t, parent, child, q, p)))
    stamps = stamps or [10**9 + i * 100_000_000 for i in range(n)]
    for i, t in enumerate(stamps):
        rgb = np.full((h, w, 3), (shades[i] if shades else 40 * i) % 256, np.uint8)
        depth = np.full((h, w), 1500, np.uint16)
        messages.append(("/camera/color/camera_info", t, info))
        made = colour(T, t, header(t)) if colour else None
        messages.append(
            (
                "/camera/color/image_raw",
                t,
                made or image(t, rgb, "rgb8", w * 3, h * w * 3 + rgb_bytes_delta),
            )
        )
        messages.append(("/camera/depth/image_raw", t, image(t, depth, "16UC1", w * 2, h * w * 2)))
    conns: dict[str, object] = {}
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        for topic, t, msg in messages:
            if topic not in conns:
                conns[topic] = writer.add_connection(topic, msg.__msgtype__, typestore=ts)
            writer.write(conns[topic], t, bytes(ts.serialize_cdr(msg, msg.__msgtype__)))
    return path


@pytest.fixture(scope="session")
def fx():
    """This conftest's helpers, for the test modules (conftest is not importable under
    pytest's importlib mode)."""
    from types import SimpleNamespace

    return SimpleNamespace(
        care_process=care_process,
        care_popen=care_popen,
        wait_for=wait_for,
        loading=loading,
        appears=appears,
        children=children,
        alive=alive,
        snapshot=snapshot,
        leftovers=leftovers,
        assert_fault=assert_fault,
        tables=tables,
        chmod=chmod,
        meta=meta,
        write_bag=write_bag,
        eval_config=eval_config,
        EVAL_FLAGS=EVAL_FLAGS,
    )
