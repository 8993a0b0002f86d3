"""The geometric consistency check of every ingest: the views sampled as they stream, judged
by :func:`care_maps.geometry.consistency.judge`, and a verdict that names the fix.

A store is only as right as the conventions it was read with, and no reader can know every
convention a user's data was written in. So the data decides: overlapping views must agree
on where the surfaces are (:mod:`care_maps.geometry.consistency`). Where they do not and a usual
mistake undone makes them agree, ingest refuses in one line naming that mistake and the
option or file field that reads the data that way; where nothing explains it, it refuses
naming the figures and ``--accept-geometry``; a recording that hardly moves cannot be
judged and says so.

:class:`GeometrySampler` keeps a bounded sample of the views while they stream (short runs
of consecutive views, spread over the recording by a stride that doubles as it grows), so
the check's memory and time do not grow with the recording.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from care_maps.core.errors import IngestError
from care_maps.core.frames import Frame
from care_maps.geometry.consistency import (
    DepthSample,
    Mistake,
    Status,
    Verdict,
    floor_support,
    judge,
    subsample,
)
from care_maps.ingest.conventions import CameraConvention, PoseConvention, QuaternionOrder
from care_maps.ingest.folders.frames import FolderFrames

__all__ = [
    "GeometrySampler",
    "SourceReading",
    "check_geometry",
    "describe_verdict",
    "refuse_unless_consistent",
    "sample_frames",
    "source_reading",
    "topics_lines",
]

RUN_VIEWS = 6
"""Consecutive views per run of the sample: pairs are taken within a run, where views
overlap."""
MAX_RUNS = 12
"""Runs kept at most (twice as many before the stride doubles): 72 to 144 views of some
4,800 depth pixels, under 3 MiB and about a second of checking whatever the recording."""
TOPICS_VIEWS = 120
"""Views ``care topics`` reads of a recording for its check (a folder's are sampled over all
its views): the first four seconds at 30 Hz."""


@dataclass
class GeometrySampler:
    """Bounded sample of the views of a stream, in runs of :data:`RUN_VIEWS` consecutive
    views: run ``r`` is kept when ``r`` is a multiple of the stride, which doubles (and drops
    every other kept run) whenever more than ``2 * MAX_RUNS`` runs are kept."""

    stride: int = 1
    seen: int = 0
    runs: dict[int, list[DepthSample]] = field(default_factory=dict)
    K: np.ndarray | None = None
    """The first view's camera matrix (full resolution), for a focal length fix."""

    def add(self, frame: Frame) -> None:
        run = self.seen // RUN_VIEWS
        self.seen += 1
        if self.K is None:
            self.K = np.asarray(frame.K, np.float64)
        if run % self.stride:
            return
        self.runs.setdefault(run, []).append(
            subsample(frame.depth_m, frame.K, frame.cam_to_world, frame.stamp_ns)
        )
        if len(self.runs) > 2 * MAX_RUNS:
            self.stride *= 2
            self.runs = {r: v for r, v in self.runs.items() if r % self.stride == 0}

    def samples(self) -> list[list[DepthSample]]:
        """The kept runs, in order."""
        return [self.runs[r] for r in sorted(self.runs)]


@dataclass(frozen=True)
class SourceReading:
    """How a source was read, so a verdict can name the option that reads it otherwise."""

    path: Path | str
    """The source, or how a recording in several files is named (its files)."""
    folder: bool
    """A dataset folder (its poses file may be in another convention) or a recording."""
    quaternion_lines: bool = False
    """The folder's poses are ``tx ty tz q q q q`` lines (a quaternion order to get wrong)."""
    depth_scale: float | None = None
    """The depth value of one metre it was read with, where known."""
    pose_convention: PoseConvention | None = None
    quaternion_order: QuaternionOrder | None = None
    camera_convention: CameraConvention | None = None

    def mistakes(self) -> list[Mistake]:
        """The usual mistakes this source can hold."""
        found = [Mistake.DEPTH_SCALE, Mistake.FOCAL_LENGTH]
        if self.folder:
            found.append(Mistake.POSES_INVERTED)
        if self.quaternion_lines:
            found.append(Mistake.QUATERNION_ORDER)
        if self.camera_convention is CameraConvention.BODY:
            found.append(Mistake.OPTICAL_AXES)
        else:
            found.append(Mistake.BODY_AXES)
        return found


def check_geometry(sampler: GeometrySampler, reading: SourceReading) -> Verdict:
    """The sample judged for the mistakes ``reading`` can hold (runs are judged as one
    sequence; pairs never span two runs)."""
    samples: list[DepthSample] = []
    for run in sampler.samples():
        samples += run
    runs = [len(run) for run in sampler.samples()]
    verdict = judge(samples, reading.mistakes(), runs=runs)
    return replace(verdict, floor=floor_support(samples)) if samples else verdict


def source_reading(path: Path | str, frames: Any, options: Any) -> SourceReading:
    """How ``frames`` (a recording's or a dataset folder's, entered) read ``path`` with the
    read ``options``: what a verdict's fix is phrased against."""
    described = frames.describe()
    topics = described.get("topics") or {}
    layout = frames.layout if isinstance(frames, FolderFrames) else None
    scale = options.depth_scale
    if scale is None and layout is not None:
        scale = topics.get("depth_scale")
    axes = described.get("camera_convention") or {}
    camera = CameraConvention(axes["convention"]) if axes.get("convention") else None
    return SourceReading(
        path=path if isinstance(path, str) else Path(path),
        folder=layout is not None,
        quaternion_lines=layout is not None and layout.pose_lines,
        depth_scale=None if scale is None else float(scale),
        pose_convention=None if layout is None else layout.pose_convention(),
        quaternion_order=None if layout is None else layout.quaternion_order(),
        camera_convention=camera or options.camera_convention,
    )


def sample_frames(frames: Iterable[Frame], limit: int) -> GeometrySampler:
    """The first ``limit`` frames of ``frames`` in a sampler (``care topics`` of a recording)."""
    sampler = GeometrySampler()
    for k, frame in enumerate(frames):
        if k >= limit:
            break
        sampler.add(frame)
    return sampler


def _percent(x: float) -> str:
    return f"{100 * x:.1f}%" if x < 0.1 else f"{100 * x:.0f}%"


def describe_verdict(verdict: dict[str, Any] | Verdict) -> str:
    """One line of what the check found (ingest's summary, ``care topics``, ``care check``)."""
    v: dict[str, Any] = verdict.as_json() if isinstance(verdict, Verdict) else verdict
    status = v.get("status")
    figures = (
        f"{_percent(v['agree'])} of reprojected depth agrees across {v['pairs_judged']} view "
        f"pairs (median residual {_percent(v['residual'])})"
        if v.get("pairs_judged")
        else "no overlapping pairs that moved"
    )
    rng = v.get("median_range_m")
    depth = f", median depth {rng:.2f} m" if rng is not None else ""
    floor = v.get("floor")
    if floor is not None and floor.get("found"):
        depth += f", floor {_percent(floor['share'])} of points, cameras {floor['camera_height_m']:.2f} m above it"
    elif floor is not None:
        depth += ", no floor under the cameras"
    if status == Status.AGREE:
        return f"geometry consistent: {figures}{depth}"
    if status == Status.UNJUDGED:
        return f"geometry not judged: too little motion or overlap among {v['views']} views ({figures}){depth}"
    if status == Status.MISTAKE:
        likelier = v["likelier"]
        return f"geometry inconsistent as read: {figures}{depth}; read as {likelier['reading']}, {_percent(likelier['agree'])} agrees"
    return f"geometry inconsistent: {figures}{depth}"


def _other(current: Any, members: list[Any]) -> Any:
    """The other member of a two-member convention enum than ``current`` (the first, the
    datasets' own, when None)."""
    first, second = members
    return first if current is second else second


def _fix(verdict: Verdict, reading: SourceReading, K: np.ndarray | None) -> str:
    """The option (or file field) that reads the source as ``verdict``'s likelier reading."""
    mistake, h = verdict.mistake, verdict.hypothesis
    assert mistake is not None
    assert h is not None
    if mistake is Mistake.POSES_INVERTED:
        other = _other(reading.pose_convention, list(PoseConvention))
        return f"the poses look {other}: pass --pose-convention {other}"
    if mistake is Mistake.QUATERNION_ORDER:
        other = _other(reading.quaternion_order, list(QuaternionOrder))
        return f"the pose quaternions look written {' '.join(other.value)}: pass --quaternion-order {other}"
    if mistake is Mistake.BODY_AXES:
        return "the camera frame looks x forward, y left, z up (a body frame): pass --camera-convention body"
    if mistake is Mistake.OPTICAL_AXES:
        return "the camera frame looks x right, y down, z forward (an optical frame): pass --camera-convention optical"
    if mistake is Mistake.DEPTH_SCALE:
        s = h.depth_scale
        how = f"{1 / s:g} times too large" if s < 1 else f"{s:g} times too small"
        if reading.depth_scale is not None:
            return f"depth reads {how}: pass --depth-scale {reading.depth_scale / s:g} (the depth value of one metre; it was read with {reading.depth_scale:g})"
        return f"depth reads {how}: pass --depth-scale with the depth value of one metre ({1000 / s:g} for 16-bit images, {1 / s:g} for 32-bit float)"
    f = h.focal_scale
    if K is None:
        return (
            f"the focal length looks {f:.2g} times the one read: give the camera with --intrinsics"
        )
    fx, fy, cx, cy = K[0, 0] * f, K[1, 1] * f, K[0, 2], K[1, 2]
    return f"the focal length looks {f:.2g} times the one read: pass --intrinsics {fx:.1f},{fy:.1f},{cx:g},{cy:g} (or the camera's calibration)"


def topics_lines(
    path: Path | str, frames: Any, options: Any, sampler: GeometrySampler | None = None
) -> list[str]:
    """``care topics``' check: the first :data:`TOPICS_VIEWS` views judged, before any
    encoding, and what ingest would say of them (``sampler``: those views, sampled already)."""
    sampler = sampler or sample_frames(frames, TOPICS_VIEWS)
    reading = source_reading(path, frames, options)
    verdict = check_geometry(sampler, reading)
    found = describe_verdict(verdict).removeprefix("geometry ")
    lines = [f"  {'geometry':<12} {found} (first {sampler.seen} views)"]
    try:
        refuse_unless_consistent(verdict, reading, sampler.K, accept=options.accept_geometry)
    except IngestError as err:
        lines.append(f"ingest would refuse: {err}")
    return lines


def refuse_unless_consistent(
    verdict: Verdict, reading: SourceReading, K: np.ndarray | None, *, accept: bool
) -> None:
    """Refuse, in one line naming the fix, geometry the views do not agree on (unless
    ``accept``: ``--accept-geometry`` keeps it as given, and the store records the verdict)."""
    if verdict.passed or accept:
        return
    found = describe_verdict(verdict)
    if verdict.status is Status.MISTAKE:
        what = _fix(verdict, reading, K)
        msg = f"{reading.path}: {found}; {what} (or --accept-geometry to keep it as given)."
    else:
        msg = f"{reading.path}: {found}, and no usual mistake (poses inverted, quaternion order, depth units, camera axes, focal length) explains it; check the poses, depth and camera, or pass --accept-geometry to keep the geometry as given."
    raise IngestError(msg)
