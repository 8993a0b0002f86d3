"""A recording as a stream of :class:`care_maps.core.frames.Frame`: topics chosen, depth matched, posed.

Two passes over the recording, so memory stays bounded whatever its length:

1. the small topics (camera info, ``/tf``, ``/tf_static``, a pose source, class names) are
   read whole into a :class:`care_maps.ingest.tf.TFBuffer` and a short camera-info history;
2. the image topics are streamed through :class:`care_maps.ingest.sync.StampSync`; only the
   messages inside the matching window are held, and each matched set becomes a Frame.

A recording in several files (split bags, MCAP files) is read the same way, its files'
messages merged in log-time order (:mod:`care_maps.ingest.parts`).

Frame conventions: the pose is ``world_from_camera`` of an *optical* frame (x right, y
down, z forward, as REP 103 prescribes for image frames) at the colour image's header stamp.
The camera frame (``--camera-frame``, default the camera info's or the image's
``header.frame_id``) may be in REP 103's body convention instead (x forward, y left, z up):
found from its name and its poses, or given (``--camera-convention``), and turned into the
optical frame (:mod:`care_maps.ingest.conventions`). The intrinsics are the camera info's, or given
(``--intrinsics``, :mod:`care_maps.ingest.intrinsics`) for recordings without a right one.

A view is one image and one pose, so whatever makes either ambiguous or impossible is one
error naming where, never a silent pick: two different transforms for one frame and stamp
(:class:`care_maps.ingest.tf.TFBuffer`), two different colour images at one stamp (the same image
again is dropped and counted as ``duplicate_stamp``), a camera farther than
``--max-translation`` from the world origin or faster than ``--max-speed`` between
consecutive frames.

A view TF does not pose at its stamp is dropped and counted by why
(:class:`care_maps.ingest.tf.Uncovered`: before the first or after the last sample of a moving
transform, or between two that never overlap); a recording whose colour images mostly have
no pose is refused, naming the TF frames, the world frame and what to pass, rather than
mapped from its few posed views.
"""

from __future__ import annotations

import hashlib
import json
import math
from collections import Counter
from collections.abc import Iterator
from dataclasses import asdict, dataclass, field, replace
from enum import StrEnum
from typing import Any, ClassVar

import numpy as np

from care_maps.core.checks import check_numbers
from care_maps.core.config import member
from care_maps.core.errors import IngestError
from care_maps.core.frames import DEFAULT_WORLD_FRAME, Frame, check_frame_id
from care_maps.ingest import decode
from care_maps.ingest.conventions import (
    CameraConvention,
    ConventionFound,
    PoseConvention,
    QuaternionOrder,
    find_convention,
    optical_pose,
)
from care_maps.ingest.folders.base import DatasetLayout
from care_maps.ingest.intrinsics import CameraIntrinsics
from care_maps.ingest.parts import (
    Recording,
    SplitReader,
    open_recording,
    parts_label,
    recording_parts,
)
from care_maps.ingest.readers import ClosedOnExit, RecordingReader, TopicInfo
from care_maps.ingest.sync import Match, StampSync
from care_maps.ingest.tf import TFBuffer, Uncovered, check_transform
from care_maps.ingest.topics import (
    TopicSelection,
    depth_camera_info,
    pose_topics,
    registered_depth_topics,
    select_topics,
)
from care_maps.ingest.undistort import Distortion, undistort

__all__ = ["PoseFrom", "ReadOptions", "ReadStats", "RecordingFrames"]

_WORLD_FRAME_NAMES = ("map", "world", "odom")
_CONVENTION_POSES = 500
"""Most TF poses the camera convention is judged on (evenly spread over the recording)."""


class PoseFrom(StrEnum):
    """Where a recording's views take their poses from (``describe()["pose"]``)."""

    TF = "tf"
    """TF's chain from the camera frame to the world frame."""
    GIVEN = "given pose source"
    """The ``--pose-source`` topic, composed with TF's chain to the camera."""
    FOUND = "found pose source"
    """The recording's odometry or pose topic, taken since TF moves nothing on the
    camera's chain (a robot's static mount chain, on ``/tf`` or ``/tf_static``)."""
    STATIC = "static pose"
    """``--static-pose``: the identity for every view."""


def _image_digest(msg: Any) -> bytes:
    """What tells two colour messages apart: their format and pixel bytes (not the header)."""
    h = hashlib.sha1(usedforsecurity=False)
    for name in ("format", "encoding", "width", "height", "step"):
        h.update(f"{name}={getattr(msg, name, None)};".encode())
    h.update(np.ascontiguousarray(np.asarray(msg.data, np.uint8)).data)  # its memoryview
    return h.digest()


@dataclass(frozen=True)
class ReadOptions:
    """How to read a recording; every field has a CLI flag of the same name."""

    rgb: str | None = None
    """Colour image topic (Image or CompressedImage); default auto-detected."""
    depth: str | None = None
    """Depth image topic registered to colour; default auto-detected."""
    camera_info: str | None = None
    """CameraInfo topic of the colour camera; default auto-detected."""
    pose_source: str | None = None
    """Odometry or PoseStamped topic to use as the pose (its child frame, or for
    PoseStamped the camera frame, is placed under its header frame at each message stamp,
    instead of TF's transform into that frame, and composed with TF's chain from there to
    the camera); default TF, or the recording's odometry where TF moves nothing on the
    camera's chain."""
    world_frame: str | None = None
    """TF frame of the world; default map, world or odom if present, else the TF root."""
    camera_frame: str | None = None
    """Frame of the colour camera; default the camera info's (or the images')
    header.frame_id."""
    camera_convention: CameraConvention | None = None
    """Axes of the camera frame: optical (x right, y down, z forward, *_optical_frame) or
    body (x forward, y left, z up, REP 103's camera_link); default found from the frame's
    name and its poses, refused where unclear.

    A body frame read as optical turns every view a quarter turn about two axes: the map is
    noise and nothing fails, so an unclear frame named like a body is refused rather than
    guessed (:mod:`care_maps.ingest.conventions`)."""
    intrinsics: CameraIntrinsics | None = None
    """Colour camera intrinsics instead of a camera info topic (a folder's calibration):
    fx,fy,cx,cy (pixels), a named camera (primesense, freiburg1, freiburg2, freiburg3) or a
    camera_info YAML / intrinsics JSON file; default the camera info topic.

    Given as text (the CLI, or Python), a file is read at once: the store records the
    numbers, so a changed file makes it stale (:mod:`care_maps.ingest.intrinsics`)."""
    max_dt: float = 0.02
    """Seconds: largest stamp difference between colour and depth (and the TF
    extrapolation allowed at the ends of a transform's samples)."""
    static_pose: bool = False
    """Identity pose for every frame, for recordings without any pose source."""
    max_translation: float = 10_000.0
    """Metres: a camera pose farther than this from the world frame's origin is refused as
    corrupt; raise it for world frames far from the views (UTM, ECEF).

    A single wild transform (1e9 m) would otherwise pass ingest and make the maps' extent,
    and so their memory, absurd, with no word of which view did it."""
    max_speed: float = 50.0
    """Metres per second: a camera that moves faster than this between consecutive frames
    is refused as a pose jump; raise it for faster platforms.

    The default (180 km/h) is above what handheld cameras, ground robots, cars in town and
    camera drones reach; a localisation glitch that moves the camera tens of metres between
    frames a tenth of a second apart is far above it. Compared between consecutive
    synchronised, posed frames, before any --start/--every/--min-motion selection."""

    depth_registered: bool = False
    """The depth topic is registered to the colour camera whatever its own camera info
    says; without it, depth whose camera info differs from the colour camera's (another
    sensor's intrinsics or frame) is refused rather than paired with the wrong pixels."""

    format: DatasetLayout | None = None
    """Read a dataset folder as this layout; default the one its file names match (a
    recording takes none)."""
    pose_convention: PoseConvention | None = None
    """A dataset folder's poses: camera-to-world (the datasets' convention) or
    world-to-camera (extrinsics); default the layout's own."""
    quaternion_order: QuaternionOrder | None = None
    """The quaternion order of a folder's pose lines: xyzw (TUM's format) or wxyz; default
    the layout's own."""
    depth_scale: float | None = None
    """The depth value of one metre (1000: millimetres), instead of what the dataset
    layout or the depth encoding says."""
    accept_geometry: bool = False
    """Keep the geometry as given when the views disagree on where the surfaces are (the
    consistency check refuses it otherwise, naming the likelier reading)."""

    HOW: ClassVar[tuple[str, ...]] = (
        "max_translation",
        "max_speed",
        "depth_registered",
        "accept_geometry",
    )
    """Fields that only refuse a recording: a store they let through is the same whatever
    their values, so they are left out of its fingerprint and recorded config (stores built
    before they existed stay current)."""

    def __post_init__(self) -> None:
        if self.camera_convention is not None:
            convention = member(
                CameraConvention, self.camera_convention, IngestError, "camera convention"
            )
            object.__setattr__(self, "camera_convention", convention)
        if isinstance(self.intrinsics, str):
            object.__setattr__(self, "intrinsics", CameraIntrinsics.from_text(self.intrinsics))
        for frame in (self.world_frame, self.camera_frame):
            if frame is not None:
                check_frame_id(frame)  # the Python API refuses what the CLI refuses
        for name, enum in (
            ("pose_convention", PoseConvention),
            ("quaternion_order", QuaternionOrder),
        ):
            value = getattr(self, name)
            if value is not None:
                object.__setattr__(self, name, member(enum, value, IngestError, name))
        if self.depth_scale is not None and not (
            math.isfinite(self.depth_scale) and self.depth_scale > 0
        ):
            msg = f"read options: --depth-scale {self.depth_scale} must be a finite positive number (the depth value of one metre)."
            raise IngestError(msg)
        if self.intrinsics is not None and self.camera_info is not None:
            msg = "read options: --intrinsics replaces the camera info topic; pass either it or --camera-info, not both."
            raise IngestError(msg)
        check_numbers(
            IngestError,
            "read options",
            non_negative={"max_dt": self.max_dt},
            positive={"max_translation": self.max_translation, "max_speed": self.max_speed},
        )


@dataclass
class ReadStats:
    """What happened to the colour messages of a recording."""

    rgb_messages: int = 0
    frames: int = 0
    dropped: Counter[str] = field(default_factory=Counter)
    lost_pixels: Counter[str] = field(default_factory=Counter)
    """Valid depth pixels of kept views that no view holds, by reason (e.g. depth outside
    the colour image's field of view when it is resampled into the colour camera)."""

    def as_dict(self) -> dict[str, Any]:
        counts: dict[str, Any] = {
            "rgb_messages": self.rgb_messages,
            "frames": self.frames,
            "dropped": dict(self.dropped),
        }
        if self.lost_pixels:
            counts["lost_pixels"] = dict(sorted(self.lost_pixels.items()))
        return counts


class RecordingFrames(ClosedOnExit):
    """Context manager over a recording; iterate it (once) for posed, synchronised frames."""

    def __init__(self, path: Recording, options: ReadOptions | None = None) -> None:
        self.parts = recording_parts(path)
        """The recording's files: one, or several in order of their first message's time
        once entered (:mod:`care_maps.ingest.parts`)."""
        self.path = self.parts[0]
        """The recording's (first) file."""
        self.where = parts_label(self.parts)
        """How messages name the recording."""
        self.options = options or ReadOptions()
        self.stats = ReadStats()
        self.label_names: tuple[str, ...] = ()
        self.topics: dict[str, TopicInfo] = {}
        self.selection: TopicSelection | None = None
        self.world_frame: str | None = None
        self.camera_frame: str | None = None
        self.convention: ConventionFound | None = None
        """The camera frame's convention and what decided it, once known."""
        self._reader: RecordingReader | None = None
        self._tf = TFBuffer()
        self._infos: list[tuple[int, np.ndarray, int, int, Distortion]] = []
        self._nearest_miss_ns: int | None = None
        self._last_pose: tuple[int, np.ndarray] | None = None
        """Stamp and camera position of the last frame yielded (for the speed bound)."""
        self._pose_from: tuple[PoseFrom, str] | None = None
        """Where the poses come from and why, once a pose source is placed (else TF's)."""
        self._lone: list[str] = []
        """Child frames of the /tf transforms kept moving though they have one sample only:
        nothing else moves the camera (:meth:`care_maps.ingest.tf.TFBuffer.thaw`)."""

    # -- pass 1 ---------------------------------------------------------------------------
    def __enter__(self) -> RecordingFrames:
        reader = open_recording(self.parts)
        self._reader = reader.__enter__()
        if isinstance(reader, SplitReader):  # now in time order
            self.parts, self.path = reader.parts, reader.path
            self.where = parts_label(self.parts)
        try:
            self._prepare()
        except IngestError as err:
            self.close()
            if self._names_where(str(err)):
                raise
            msg = f"{self.where}: {err}"
            raise IngestError(msg) from err
        except BaseException:
            self.close()
            raise
        return self

    def close(self) -> None:
        if self._reader is not None:
            reader, self._reader = self._reader, None
            reader.__exit__(None, None, None)

    def _prepare(self) -> None:
        assert self._reader is not None
        o = self.options
        self.topics = self._reader.topics()
        sel = select_topics(
            self.topics,
            path=self.where,
            rgb=o.rgb,
            depth=o.depth,
            camera_info=o.camera_info,
            pose_source=o.pose_source,
            intrinsics=o.intrinsics is not None,
        )
        self.selection = sel
        if isinstance(self._reader, SplitReader):
            self._reader.check_frames(sel.rgb)
        if not o.static_pose and not sel.tf and not sel.pose_source:
            msg = f"{self.where}: no pose source: no /tf or /tf_static messages and no nav_msgs/Odometry or geometry_msgs/PoseStamped topic; pass --static-pose to give every frame the identity pose, or --pose-source TOPIC."
            raise IngestError(msg)
        depth_info = None if o.depth_registered else depth_camera_info(self.topics, sel)
        # a pose topic TF may not need: read with the small topics, taken as the pose source
        # if TF turns out to move nothing on the camera's chain (a static chain on /tf)
        candidate = None
        if not sel.pose_source and not o.static_pose and (found := pose_topics(self.topics)):
            candidate = found[0]
        small = [*sel.tf, *filter(None, [sel.camera_info, sel.pose_source, sel.class_names])]
        small += [candidate] if candidate else []
        small += [depth_info] if depth_info else []
        pose_samples: list[decode.StampedTransform] = []
        depth_intrinsics: tuple[np.ndarray, int, int, str] | None = None
        # no small topic at all (--intrinsics and --static-pose): nothing to read, and an
        # empty list would ask the reader for every topic
        for topic, t, msg in self._reader.messages(small) if small else ():
            if topic == sel.camera_info:
                self._add_info(msg, t)
            elif topic == depth_info:
                if depth_intrinsics is None:
                    K, w, h = decode.camera_info(msg, topic)
                    depth_intrinsics = (K, w, h, str(msg.header.frame_id).lstrip("/"))
            elif topic == sel.class_names:
                self.label_names = self._parse_names(msg.data, topic)
            elif topic in (sel.pose_source, candidate):
                sample = decode.pose_sample(msg, t)
                check_transform(sample, f"pose source {topic}")
                pose_samples.append(sample)
            elif not o.static_pose:
                static = topic.rstrip("/").endswith("tf_static")
                for tf in decode.transforms(msg, t):
                    self._tf.add(tf, static=static, topic=topic)
        if o.intrinsics is not None:
            given = o.intrinsics
            self._infos = [(0, given.K, given.width, given.height, given.lens)]
        if not self._infos:
            msg = f"{self.where}: camera info topic {sel.camera_info} has no messages; record camera_info, pass --camera-info TOPIC, or give the intrinsics with --intrinsics fx,fy,cx,cy (or a camera_info YAML)."
            raise IngestError(msg)
        if self.camera_frame is None and not o.camera_frame:
            self.camera_frame = self._first_image_frame()
        colour_frame = self.camera_frame
        self.camera_frame = o.camera_frame or self.camera_frame
        if depth_info and depth_intrinsics is not None:
            self._check_depth_registered(depth_info, depth_intrinsics, colour_frame)
        if not o.static_pose:
            self._tf.freeze_unchanging()
            self._place_pose_source(candidate, pose_samples)
        if not o.static_pose and self.camera_frame:
            self._resolve_world_frame()
        if o.static_pose:  # the camera frame is the world: any convention is consistent
            stated = o.camera_convention or CameraConvention.OPTICAL
            self.convention = ConventionFound(stated, "static pose")

    def _first_image_frame(self) -> str | None:
        """The first colour image's ``header.frame_id`` (no camera info names the frame):
        read now, so the world frame and the convention are checked before any model loads."""
        assert self._reader is not None
        assert self.selection is not None
        for _, _, msg in self._reader.messages([self.selection.rgb]):
            return str(msg.header.frame_id).lstrip("/") or None
        return None

    def _check_depth_registered(
        self, topic: str, depth: tuple[np.ndarray, int, int, str], colour_frame: str | None
    ) -> None:
        """Refuse depth that comes from another sensor than the colour camera: its own
        camera info has other intrinsics (compared at the colour image's size) or names
        another optical frame. Such depth paired pixel by pixel with colour puts every
        point in the wrong place."""
        sel = self.selection
        assert sel is not None
        Kd, wd, hd, frame = depth
        _, Kc, wc, hc, _ = self._infos[0]
        scaled = Kd.copy()
        if wd and hd and wc and hc:
            scaled[0] *= wc / wd
            scaled[1] *= hc / hd
        same_k = np.allclose(scaled, Kc, rtol=1e-3, atol=0.5)
        same_frame = not frame or not colour_frame or frame == colour_frame
        if same_k and same_frame:
            return
        found = (
            f"fx {Kd[0, 0]:.1f}, fy {Kd[1, 1]:.1f} against the colour camera's "
            f"{Kc[0, 0]:.1f}, {Kc[1, 1]:.1f}"
            if not same_k
            else f"frame {frame} against the colour camera's {colour_frame}"
        )
        aligned = [t for t in registered_depth_topics(self.topics, sel.rgb) if t != sel.depth]
        fix = (
            f"pass --depth {aligned[0]} (registered to colour)"
            if aligned
            else "record depth registered to the colour camera (a driver's "
            "aligned_depth_to_color topic, e.g. realsense2_camera align_depth:=true)"
        )
        msg = (
            f"{self.where}: depth {sel.depth} comes from another sensor than {sel.rgb} (its "
            f"camera info {topic}: {found}); {fix}, or pass --depth-registered if it is "
            "registered already."
        )
        raise IngestError(msg)

    def _place_pose_source(
        self, candidate: str | None, samples: list[decode.StampedTransform]
    ) -> None:
        """Put the pose source into TF: the one given (``--pose-source``), or the recording's
        first odometry or pose topic (``candidate``) where TF moves nothing on the camera's
        chain, as on a robot whose motion is on ``nav_msgs/Odometry`` and whose mount chain
        is static (REP 105), wherever that chain was published."""
        assert self.selection is not None
        if candidate and samples:
            still = self._tf.moving(self.camera_frame) if self.camera_frame else self._tf.moving()
            if still:  # TF moves the camera itself: the odometry read along is not needed
                return
            self.selection = replace(self.selection, pose_source=candidate)
        if self.selection.pose_source and samples:
            self._add_pose_source(samples)
        elif self.camera_frame and not self._tf.moving(self.camera_frame):
            self._lone = self._tf.lone(self.camera_frame)
            self._tf.thaw(self._lone)

    def _add_pose_source(self, samples: list[decode.StampedTransform]) -> None:
        """Put the pose source's samples into TF, replacing TF's own transform to its child:
        a given source wins over whatever TF says moves that frame (said in
        :meth:`describe`), and any chain TF holds from there to the camera, static or
        moving, is composed with it."""
        assert self.selection is not None
        topic = self.selection.pose_source
        child = samples[0].child or self.camera_frame
        if not child:
            msg = f"{self.where}: pose source {topic} is a PoseStamped and the camera frame is unknown; pass --camera-frame."
            raise IngestError(msg)
        parent = samples[0].parent
        replaced = self._tf.describe_edge(child)
        self._tf.drop(child)
        for sample in samples:
            self._tf.add(sample._replace(child=child), static=False, topic=topic)
        kind = PoseFrom.GIVEN if self.options.pose_source else PoseFrom.FOUND
        why = (
            f"--pose-source {topic} given"
            if kind is PoseFrom.GIVEN
            else f"{topic}, since TF moves nothing on the camera's chain"
        )
        instead = f", instead of TF's {replaced}" if replaced else ""
        self._pose_from = (
            kind,
            f"{why}: it places {child!r} under {parent!r} at each message stamp{instead}",
        )

    def _add_info(self, msg: Any, t: int) -> None:
        topic = self.selection.camera_info if self.selection else ""
        K, w, h = decode.camera_info(msg, topic)
        lens = decode.distortion(msg, topic)
        if not self.camera_frame:
            self.camera_frame = str(msg.header.frame_id).lstrip("/") or None
        last = self._infos[-1] if self._infos else None
        if last is None or not (np.array_equal(last[1], K) and last[2:] == (w, h, lens)):
            self._infos.append((decode.stamp_ns(msg, t), K, w, h, lens))

    @property
    def distortions(self) -> list[Distortion]:
        """The non-zero lens distortions of the camera infos, in order of first appearance:
        what is removed from the images (none: the images are stored as recorded)."""
        seen: list[Distortion] = []
        for *_, lens in self._infos:
            if not lens.is_zero and lens not in seen:
                seen.append(lens)
        return seen

    def _parse_names(self, text: str, topic: str) -> tuple[str, ...]:
        try:
            names = json.loads(text)
        except json.JSONDecodeError as err:
            msg = f"{self.where}: topic {topic} is not a JSON list of class names ({err}); fix or drop the topic."
            raise IngestError(msg) from err
        if not isinstance(names, list) or not all(isinstance(n, str) for n in names):
            msg = f"{self.where}: topic {topic} must hold a JSON list of strings."
            raise IngestError(msg)
        return tuple(names)

    def _choose_world_frame(self) -> str:
        if self.options.world_frame:
            return self.options.world_frame
        assert self.camera_frame is not None
        frames = self._tf.frames
        if self.camera_frame not in frames:
            return next((f for f in _WORLD_FRAME_NAMES if f in frames), DEFAULT_WORLD_FRAME)
        root = self._tf.root(self.camera_frame)
        chain = {root}
        chain.update(f for f in frames if self._tf.root(f) == root)
        found = next((f for f in _WORLD_FRAME_NAMES if f in chain), None)
        if found is not None:
            return found
        # the camera's tree has no world frame: if another tree has one, the camera hangs
        # under a frame TF never joins to the world (taking its root as the world would
        # give every view the same, meaningless pose)
        elsewhere = next((f for f in _WORLD_FRAME_NAMES if f in frames), None)
        if elsewhere is not None:
            msg = (
                f"{self.where}: camera frame {self.camera_frame!r} is not connected to world "
                f"frame {elsewhere!r}: {self._tf.describe_tree(self.camera_frame)}, "
                f"{self._tf.describe_tree(elsewhere)}; record the transform that joins them, "
                f"or pass --world-frame {root} to map in the camera's own tree"
            )
            raise IngestError(msg)
        return root

    def describe(self) -> dict[str, Any]:
        """The choices made, for ``care topics`` and the store's meta.json."""
        return {
            "topics": self.selection.as_dict() if self.selection else None,
            "pose": self._describe_pose(),
            "world_frame": self.world_frame,
            "camera_frame": self.camera_frame,
            "camera_convention": self.convention.as_json() if self.convention else None,
            "label_names": list(self.label_names),
            "options": asdict(self.options),
        }

    def _describe_pose(self) -> dict[str, str]:
        """Where the views' poses come from and why (a given ``--pose-source`` wins over
        TF's own transform of its frame, and says so)."""
        if self.options.static_pose:
            kind, reason = PoseFrom.STATIC, "--static-pose: the identity for every view"
        elif self._pose_from is not None:
            kind, reason = self._pose_from
        else:
            kind, reason = PoseFrom.TF, f"TF from {self.camera_frame!r} to {self.world_frame!r}"
        return {"from": kind.value, "reason": reason}

    # -- pass 2 ---------------------------------------------------------------------------
    def __iter__(self) -> Iterator[Frame]:
        if self._reader is None or self.selection is None:
            msg = "RecordingFrames must be entered (with ...) before iterating"
            raise IngestError(msg)
        sel = self.selection
        streams = {sel.depth: "depth", **{topic: key for key, topic in sel.extras.items()}}
        sync = StampSync(
            {"depth": True, **dict.fromkeys(sel.extras, False)},
            max_dt_ns=round(self.options.max_dt * 1e9),
        )
        seen: dict[int, bytes] = {}  # colour stamp -> digest of its image
        for topic, t, msg in self._reader.messages([sel.rgb, *streams]):
            stamp = decode.stamp_ns(msg, t)
            if topic == sel.rgb:
                self.stats.rgb_messages += 1
                self._learn_camera_frame(msg)
                digest = _image_digest(msg)
                if stamp in seen:
                    self._check_repeat(stamp, seen[stamp], digest)
                    self.stats.dropped["duplicate_stamp"] += 1
                    continue
                seen[stamp] = digest
            for match in sync.push(None if topic == sel.rgb else streams[topic], stamp, msg):
                frame = self._assemble(match)
                if frame is not None:
                    self._check_pose(frame)
                    self.stats.frames += 1
                    yield frame
        for match in sync.finish():
            frame = self._assemble(match)
            if frame is not None:
                self._check_pose(frame)
                self.stats.frames += 1
                yield frame
        self.stats.dropped.update(sync.dropped)
        self._nearest_miss_ns = sync.nearest_miss.get("depth")
        if self._unposed() * 2 > self.stats.rgb_messages:
            raise IngestError(self._why_unposed())
        if self.stats.frames == 0:
            raise IngestError(self._why_empty())

    def _check_repeat(self, stamp: int, first: bytes, digest: bytes) -> None:
        """A second colour image at a stamp: the same image again is dropped and counted
        (a message recorded twice); a different one is refused, since which image is the view
        there is undecidable and the pose at that stamp belongs to one of them at most."""
        if digest == first:
            return
        assert self.selection is not None
        msg = f"{self.where}: colour topic {self.selection.rgb} has different images at one stamp, {stamp} ns; the view there is ambiguous (the camera's header stamps are not unique: re-stamp the images in the recording, or pass --rgb TOPIC)."
        raise IngestError(msg)

    def _check_pose(self, frame: Frame) -> None:
        """Refuse a pose no camera can have: farther than ``max_translation`` from the world
        origin, or reached faster than ``max_speed`` from the previous frame's pose. Both
        come from corrupt transforms (a glitch, a unit error), and a view placed there would
        stretch every map built from the store."""
        if self.options.static_pose:
            return
        o = self.options
        position = np.asarray(frame.cam_to_world[:3, 3], np.float64)
        view = (
            f"{self.where}: view {self.stats.frames} at stamp {frame.stamp_ns} ns: camera frame "
            f"{self.camera_frame!r} in world frame {self.world_frame!r}"
        )
        distance = float(np.linalg.norm(position))
        if distance > o.max_translation:
            msg = f"{view} lies {distance:.4g} m from the origin (translation {position.tolist()}), beyond --max-translation {o.max_translation:g} m; the recording's transforms are corrupt there (fix them or pass --pose-source TOPIC), or, if the world is that large, raise --max-translation."
            raise IngestError(msg)
        if self._last_pose is not None:
            last_stamp, last_position = self._last_pose
            step = float(np.linalg.norm(position - last_position))
            dt = abs(frame.stamp_ns - last_stamp) / 1e9
            # equal stamps never reach here (a repeated colour stamp is dropped or refused);
            # were they to, any step would be an infinite speed
            speed = step / dt if dt > 0 else (math.inf if step > 0 else 0.0)
            if speed > o.max_speed:
                msg = f"{view} moved {step:.4g} m in {dt * 1e3:.4g} ms since the previous view (stamp {last_stamp} ns): {speed:.4g} m/s, faster than --max-speed {o.max_speed:g} m/s; the recording's transforms jump there (fix them or pass --pose-source TOPIC), or, if the camera moves that fast, raise --max-speed."
                raise IngestError(msg)
        self._last_pose = (frame.stamp_ns, position)

    def _learn_camera_frame(self, msg: Any) -> None:
        if self.camera_frame is None:
            self.camera_frame = str(msg.header.frame_id).lstrip("/") or None
            if self.camera_frame is None and not self.options.static_pose:
                msg_ = f"{self.where}: neither the camera info nor the images name their frame (header.frame_id); pass --camera-frame."
                raise IngestError(msg_)
        if self.world_frame is None and not self.options.static_pose:
            self._resolve_world_frame()

    def _resolve_world_frame(self) -> None:
        """Pick the world frame and fail early, naming both frames, if TF cannot join them."""
        self.world_frame = self._choose_world_frame()
        assert self.camera_frame is not None
        self._tf.check_connected(self.world_frame, self.camera_frame)
        self.convention = self._find_convention()

    def _find_convention(self) -> ConventionFound:
        """The camera frame's convention: as given, else from its name and its poses at TF's
        own stamps (no image decoded)."""
        given = self.options.camera_convention
        if given is not None:
            return ConventionFound(given, "given (--camera-convention)")
        assert self.world_frame is not None
        assert self.camera_frame is not None
        stamps = self._tf.sample_stamps(self.world_frame, self.camera_frame)
        if len(stamps) > _CONVENTION_POSES:
            spread = np.linspace(0, len(stamps) - 1, _CONVENTION_POSES).round().astype(int)
            stamps = stamps[spread]
        if not len(stamps):  # a static chain: one pose at any time
            stamps = np.zeros(1, np.int64)
        poses, valid = self._tf.lookup(self.world_frame, self.camera_frame, stamps)
        return find_convention(self.camera_frame, self.world_frame, poses[valid])

    def _why_empty(self) -> str:
        sel = self.selection
        assert sel is not None
        d = self.stats.dropped
        if self.stats.rgb_messages == 0:
            return f"{self.where}: colour topic {sel.rgb} has no messages; pass --rgb TOPIC."
        if d["no_depth"]:
            near = (
                ""
                if self._nearest_miss_ns is None
                else f" (nearest was {self._nearest_miss_ns / 1e6:.0f} ms)"
            )
            return f"{self.where}: no colour image on {sel.rgb} has a depth image on {sel.depth} within --max-dt {self.options.max_dt * 1e3:.0f} ms{near}; raise --max-dt or pass --depth TOPIC."
        if d["no_valid_depth"]:
            return f"{self.where}: depth topic {sel.depth} has no valid pixel (finite and > 0) in any of {d['no_valid_depth']} frames; check the depth topic and its encoding."
        if self._unposed():
            return self._why_unposed()
        return f"{self.where}: no frame could be read ({dict(d)})."

    def _unposed(self) -> int:
        """Colour images dropped so far for want of a pose, whatever the reason."""
        return sum(self.stats.dropped[reason.value] for reason in Uncovered)

    def _drop_unposed(self, stamp: int) -> None:
        """Count a view TF does not pose at ``stamp`` under why, and refuse the recording as
        soon as most of its colour images surely have no pose: a map of the few posed views
        is not what was recorded, and the fix (another pose source, another world frame) is
        for the user to pass, not for ingest to guess."""
        assert self.world_frame is not None
        assert self.camera_frame is not None
        tolerance = round(self.options.max_dt * 1e9)
        reason = self._tf.uncovered(self.world_frame, self.camera_frame, stamp, tolerance)
        self.stats.dropped[reason.value] += 1
        if self.total and self._unposed() * 2 > self.total:  # a count of 0: known at the end
            raise IngestError(self._why_unposed())

    def _why_unposed(self) -> str:
        """The one line refusing a recording whose views mostly have no pose: how many and
        why, what TF covers, the frames it holds, the world frame chosen, what to pass."""
        sel = self.selection
        assert sel is not None
        assert self.world_frame is not None
        assert self.camera_frame is not None
        total = max(self.total or 0, self.stats.rgb_messages)
        reasons = ", ".join(
            f"{r.value} {self.stats.dropped[r.value]}"
            for r in Uncovered
            if self.stats.dropped[r.value]
        )
        spans = self._tf.spans(self.world_frame, self.camera_frame)
        covered = ", ".join(
            f"{self._tf.parent(child)}->{child} {first / 1e9:.3f}-{last / 1e9:.3f} s"
            for child, (first, last) in spans.items()
        )
        chosen = "given" if self.options.world_frame else "chosen"
        using = f"; poses from {sel.pose_source}" if sel.pose_source else ""
        others = [t for t in pose_topics(self.topics) if t != sel.pose_source]
        world = "--world-frame FRAME (a frame whose tree covers the recording)"
        fix = (
            f"pass --pose-source {others[0]} (the recording's odometry/pose topics: {', '.join(others)}), or {world}"
            if others
            else f"the recording has no other odometry or pose topic: record the transforms that move the camera, or pass {world}"
        )
        if self._lone:
            edges = ", ".join(f"{self._tf.parent(c)}->{c}" for c in self._lone)
            fix += f"; if {edges} is a fixed mount, publish it on /tf_static"
        return (
            f"{self.where}: {self._unposed()} of {total} colour images on {sel.rgb} have no "
            f"pose ({reasons}; colour stamps checked against the transforms' samples "
            f"± --max-dt {self.options.max_dt * 1e3:g} ms): the moving transforms from camera "
            f"frame {self.camera_frame!r} to world frame {self.world_frame!r} ({chosen}) "
            f"cover only {covered}{using}; TF frames: {', '.join(sorted(self._tf.frames))}; "
            f"{fix}."
        )

    def _assemble(self, match: Match) -> Frame | None:
        try:
            return self._assemble_checked(match)
        except IngestError as err:
            if self._names_where(str(err)):
                raise
            msg = f"{self.where}: {err}"
            raise IngestError(msg) from err

    def _names_where(self, line: str) -> bool:
        """Whether an error's line already starts with the recording or one of its files."""
        return any(line.startswith(str(name)) for name in (self.where, *self.parts))

    def _assemble_checked(self, match: Match) -> Frame | None:
        sel = self.selection
        assert sel is not None
        decoded, jpeg = decode.decode_colour_kept(match.primary, sel.rgb)
        rgb = decoded
        depth = decode.decode_depth(match.secondary["depth"], sel.depth, self.options.depth_scale)
        h, w = rgb.shape[:2]
        if depth.shape != (h, w):
            msg = f"{self.where}: colour images on {sel.rgb} are {w}x{h} but depth images on {sel.depth} are {depth.shape[1]}x{depth.shape[0]}; record depth registered to colour (e.g. aligned_depth_to_color) or pass --depth TOPIC."
            raise IngestError(msg)
        K, lens = self._intrinsics(match.stamp_ns, w, h)
        rgb = undistort(rgb, K, lens, blend=True)
        depth = undistort(depth, K, lens, blend=False)
        if not depth.any():
            self.stats.dropped["no_valid_depth"] += 1
            return None
        pose = self._pose(match.stamp_ns)
        if pose is None:
            self._drop_unposed(match.stamp_ns)
            return None
        extras = {}
        for key, msg in match.secondary.items():
            if key == "depth" or msg is None:
                continue
            label = decode.decode_label(msg, sel.extras[key])
            if label.shape != (h, w):
                msg_ = f"{self.where}: label images on {sel.extras[key]} are {label.shape[1]}x{label.shape[0]}, colour images {w}x{h}; they must match."
                raise IngestError(msg_)
            extras[key] = undistort(label, K, lens, blend=False)
        kept = jpeg if rgb is decoded else None  # undistorted: other pixels than those bytes
        return Frame(match.stamp_ns, rgb, depth, K, pose, extras, rgb_jpeg=kept)

    def _intrinsics(self, t: int, w: int, h: int) -> tuple[np.ndarray, Distortion]:
        """K and lens distortion of the camera info nearest in time to ``t``."""
        stamps = np.array([i[0] for i in self._infos])
        _, K, iw, ih, lens = self._infos[int(np.argmin(np.abs(stamps - t)))]
        if (iw, ih) != (0, 0) and (iw, ih) != (w, h):
            sel = self.selection
            assert sel is not None
            if self.options.intrinsics is not None:
                msg = f"{self.where}: --intrinsics are for {iw}x{ih} images but {sel.rgb} has {w}x{h}; give the colour camera's intrinsics."
            else:
                msg = f"{self.where}: camera info {sel.camera_info} is for {iw}x{ih} images but {sel.rgb} has {w}x{h}; pass the colour camera's --camera-info, or --intrinsics."
            raise IngestError(msg)
        return K, lens

    def _pose(self, t: int) -> np.ndarray | None:
        """``world_from_optical`` at ``t`` (None: TF does not cover it)."""
        convention = self.convention.convention if self.convention else CameraConvention.OPTICAL
        if self.options.static_pose:
            return optical_pose(np.eye(4), convention)
        assert self.world_frame is not None
        assert self.camera_frame is not None
        T, valid = self._tf.lookup(
            self.world_frame, self.camera_frame, np.array([t]), round(self.options.max_dt * 1e9)
        )
        return optical_pose(T[0], convention) if valid[0] else None

    @property
    def total(self) -> int | None:
        """Colour images the recording holds (the progress bar's length), once entered."""
        return self.topics[self.selection.rgb].count if self.selection else None
