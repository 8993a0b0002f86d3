"""Procedural indoor scenes, deterministic from a seed: floor plan, walls with doors, furniture.

Layout: 1 to 6 rectangular rooms in one or two rows; neighbours in a row share a door,
and the rows are joined by one door. Furniture is placed room by room from the room type's
list: pieces go against a wall, free in the room (a table with its chairs around it), on top
of other furniture (a lamp on a nightstand, a tv on a tv stand) or hung on a wall. A candidate
placement is rejected if any of its parts comes within a margin of another object's part,
leaves the room, or covers the *navigation zone* (a free disk at the room centre and free
corridors from the centre through each door) that the camera trajectory will follow, so the
trajectory is collision-free by construction.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import StrEnum
from functools import cached_property
from typing import Any

import numpy as np

from care_maps.truth.model import GroundTruth, Room, instances_table
from care_maps.world.catalogue import (
    CATALOGUE,
    CLASS_NAMES,
    COMPANIONS,
    ROOM_TYPES,
    Built,
    ClassSpec,
    RoomType,
    build_instance,
)
from care_maps.world.meshes import Mesh, Part, merge_meshes, rotate_part, sample_surface

__all__ = [
    "CEILING_HEIGHT",
    "GENERATOR_VERSION",
    "Catalogue",
    "Door",
    "PlacedObject",
    "Scene",
    "SceneConfig",
    "class_names_of",
    "generate_scene",
]

GENERATOR_VERSION = "1"
WALL_THICKNESS = 0.1
CEILING_HEIGHT = 2.6
DOOR_WIDTH = 0.9
DOOR_HEIGHT = 2.1
NAV_RADIUS = 0.75
"""Radius of the free disk at each room centre (where the camera turns round)."""
CORRIDOR_HALF_WIDTH = 0.45
PLACE_MARGIN = 0.03
"""Smallest gap between two objects placed side by side."""
NAV_CELL = 0.05

STRUCTURE_COLOURS = {
    "wall": (0.85, 0.83, 0.78),
    "floor": (0.55, 0.45, 0.35),
    "ceiling": (0.95, 0.95, 0.95),
}


class Catalogue(StrEnum):
    """Which object catalogue a scene is furnished from."""

    SAMPLE = "sample"
    """The 51 classes of :mod:`care_maps.world.catalogue` (the sample world of every release)."""
    MATTERPORT = "matterport"
    """The 229 classes of :mod:`care_maps.world.matterport_catalogue`, near-synonyms included."""


@dataclass(frozen=True)
class _Kit:
    """A catalogue with its room contents: what a furnisher needs."""

    classes: dict[str, ClassSpec]
    class_names: tuple[str, ...]
    room_types: dict[str, RoomType]
    companions: dict[str, tuple[str, tuple[int, int], tuple[int, ...]]]
    fill: dict[str, tuple[str, ...]]


def _kit(catalogue: Catalogue) -> _Kit:
    if Catalogue(catalogue) is Catalogue.SAMPLE:
        return _Kit(CATALOGUE, CLASS_NAMES, ROOM_TYPES, COMPANIONS, {})
    from care_maps.world import matterport_catalogue as mp

    return _Kit(
        mp.MATTERPORT_CATALOGUE,
        mp.MATTERPORT_CLASS_NAMES,
        mp.MATTERPORT_ROOM_TYPES,
        mp.MATTERPORT_COMPANIONS,
        mp.MATTERPORT_FILL,
    )


def class_names_of(catalogue: Catalogue) -> tuple[str, ...]:
    """Class id -> name of the scenes furnished from ``catalogue``."""
    return _kit(catalogue).class_names


@dataclass(frozen=True)
class SceneConfig:
    """How to generate a scene; ``seed`` alone fixes everything else left at its default."""

    seed: int = 0
    """Seed of every random choice."""
    num_rooms: int | None = None
    """Rooms, 1 to 6; default drawn from 2 to 5."""
    room_types: tuple[str, ...] | None = None
    """Kinds of the rooms in order (names of ``ROOM_TYPES``); default drawn."""
    clutter: float = 1.0
    """Multiplies the probability of each optional piece of furniture (0 = only the sure ones)."""
    point_density_objects: float = 1500.0
    """Ground-truth surface points per square metre on objects."""
    point_density_structure: float = 150.0
    """Ground-truth surface points per square metre on walls, floors and ceilings."""
    catalogue: Catalogue = Catalogue.SAMPLE
    """Object catalogue and room contents (``sample``: 51 classes; ``matterport``: 229)."""
    instances_per_room: int = 0
    """After the furniture, fill each room with small, hung and floor objects of its kind
    (catalogues that list them) until it holds about this many instances (a target drawn
    per room from 0.6 to 1.4 times it, as long as there is space); 0 = no filling."""
    sibling_weight: float = 3.0
    """While filling, a class already drawn in the room is this many times as likely to be
    drawn again (same-class siblings: four pillows, three pictures)."""


@dataclass(frozen=True)
class Door:
    """A door gap in a wall line: ``axis`` 0 = wall along x at y = coord, 1 = along y at x = coord."""

    rooms: tuple[int, int]
    axis: int
    coord: float
    centre: float

    def points(self, offset: float) -> tuple[np.ndarray, np.ndarray]:
        """Points ``offset`` metres either side of the door's middle, on the line through it."""
        mid = (
            np.array([self.centre, self.coord])
            if self.axis == 0
            else np.array([self.coord, self.centre])
        )
        normal = np.array([0.0, 1.0]) if self.axis == 0 else np.array([1.0, 0.0])
        return mid - offset * normal, mid + offset * normal


@dataclass(frozen=True, eq=False)
class PlacedObject:
    """One object instance in world coordinates."""

    instance_id: int
    class_name: str
    room_id: int
    parts: tuple[Part, ...]
    support_id: int = 0
    """Instance it rests on, 0 = the floor or a wall."""
    surface: tuple[float, float, float, float, float] | None = None
    """World-frame support surface (xmin, xmax, ymin, ymax, z) if others may rest on it."""

    @cached_property
    def part_boxes(self) -> np.ndarray:
        """(K, 2, 3) bounds of each part."""
        return np.stack([np.stack(p.bbox) for p in self.parts])

    @property
    def bbox(self) -> tuple[np.ndarray, np.ndarray]:
        b = self.part_boxes
        return b[:, 0].min(axis=0), b[:, 1].max(axis=0)


@dataclass(frozen=True, eq=False)
class Scene:
    """A generated scene: rooms, walls, doors and objects."""

    config: SceneConfig
    rooms: list[Room]
    room_rects: np.ndarray
    """(R, 4) room rectangles x0, y0, x1, y1 on the wall centre lines."""
    doors: list[Door]
    structure: dict[str, list[Part]]
    """``wall``, ``floor``, ``ceiling`` parts."""
    objects: list[PlacedObject]
    nav_mask: np.ndarray = field(repr=False)
    """(nx, ny) bool cells of the navigation zone (kept free of furniture)."""
    nav_origin: np.ndarray = field(repr=False)

    @cached_property
    def mesh(self) -> Mesh:
        """The whole scene as one labelled triangle mesh."""
        cid = {n: i for i, n in enumerate(self.class_names)}
        groups = [(0, cid[name], parts) for name, parts in self.structure.items()]
        groups += [(o.instance_id, cid[o.class_name], list(o.parts)) for o in self.objects]
        return merge_meshes(groups)

    @property
    def class_names(self) -> tuple[str, ...]:
        return class_names_of(self.config.catalogue)

    def _catalogue_info(self) -> dict[str, Any]:
        """The catalogue and filling, where they differ from the sample world's (so the
        ground truth of a default scene keeps its bytes)."""
        c = self.config
        if c.catalogue is Catalogue.SAMPLE and c.instances_per_room == 0:
            return {}
        return {
            "catalogue": str(c.catalogue),
            "instances_per_room": c.instances_per_room,
            "sibling_weight": c.sibling_weight,
        }

    def ground_truth(self, info: dict[str, Any] | None = None) -> GroundTruth:
        """Ground truth with surface points sampled deterministically from the seed."""
        mesh = self.mesh
        density = np.where(
            mesh.tri_instance > 0,
            self.config.point_density_objects,
            self.config.point_density_structure,
        )
        rng = np.random.default_rng([self.config.seed, 7])
        pts, tri = sample_surface(mesh, density, rng)
        cid = {n: i for i, n in enumerate(self.class_names)}
        rows = []
        for o in self.objects:
            lo, hi = o.bbox
            rows.append(
                {
                    "instance_id": o.instance_id,
                    "class_name": o.class_name,
                    "class_id": cid[o.class_name],
                    "room_id": o.room_id,
                    "bbox_min": np.round(lo, 5).tolist(),
                    "bbox_max": np.round(hi, 5).tolist(),
                }
            )
        full_info = {
            "generator": "care.world",
            "generator_version": GENERATOR_VERSION,
            "scene": {
                "seed": self.config.seed,
                "num_rooms": len(self.rooms),
                "room_types": [r.name for r in self.rooms],
                "clutter": self.config.clutter,
                **self._catalogue_info(),
            },
            **(info or {}),
        }
        return GroundTruth(
            class_names=self.class_names,
            instances=instances_table(rows),
            rooms=self.rooms,
            points=pts,
            point_instance=mesh.tri_instance[tri].astype(np.int32),
            info=full_info,
        )


# ----------------------------------------------------------------------------- floor plan
def _split(total: float, n: int, minimum: float, rng: np.random.Generator) -> np.ndarray:
    extra = total - n * minimum
    return minimum + extra * rng.dirichlet(np.full(n, 3.0))


def _floor_plan(n: int, rng: np.random.Generator) -> tuple[np.ndarray, list[Door]]:
    rows = [n] if n <= 3 else [(n + 1) // 2, n // 2]
    width = float(rng.uniform(3.8, 4.8) * max(rows))
    depths = rng.uniform(3.6, 4.8, len(rows))
    rects: list[list[float]] = []
    row_of: list[int] = []
    y0 = 0.0
    for r, count in enumerate(rows):
        widths = _split(width, count, 3.4, rng)
        x0 = 0.0
        for w in widths:
            rects.append([x0, y0, x0 + float(w), y0 + float(depths[r])])
            row_of.append(r)
            x0 += float(w)
        y0 += float(depths[r])
    rect = np.asarray(rects)
    doors: list[Door] = []
    margin = 0.6 + DOOR_WIDTH / 2
    for i in range(len(rect)):
        for j in range(i + 1, len(rect)):
            a, b = rect[i], rect[j]
            if row_of[i] == row_of[j] and np.isclose(a[2], b[0]):
                c = rng.uniform(a[1] + margin, a[3] - margin)
                doors.append(Door((i, j), 1, float(a[2]), float(c)))
    if len(rows) == 2:
        top = [i for i in range(len(rect)) if row_of[i] == 0]
        bottom = [i for i in range(len(rect)) if row_of[i] == 1]
        pairs = [
            (min(rect[i, 2], rect[j, 2]) - max(rect[i, 0], rect[j, 0]), i, j)
            for i in top
            for j in bottom
        ]
        pairs.sort(reverse=True)
        chosen = [pairs[0]] + [p for p in pairs[1:] if p[0] > 2.5 and rng.random() < 0.4]
        for overlap, i, j in chosen:
            lo = max(rect[i, 0], rect[j, 0]) + margin
            hi = lo - 2 * margin + overlap
            doors.append(Door((i, j), 0, float(rect[i, 3]), float(rng.uniform(lo, max(lo, hi)))))
    return rect, doors


def _walls(rect: np.ndarray, doors: list[Door]) -> list[Part]:
    """Wall boxes along every room edge, merged per line, with door gaps and lintels."""
    colour = STRUCTURE_COLOURS["wall"]
    lines: dict[tuple[int, float], list[tuple[float, float]]] = {}
    for x0, y0, x1, y1 in rect:
        for axis, coord, lo, hi in (
            (0, y0, x0, x1),
            (0, y1, x0, x1),
            (1, x0, y0, y1),
            (1, x1, y0, y1),
        ):
            lines.setdefault((axis, round(float(coord), 6)), []).append((float(lo), float(hi)))
    parts: list[Part] = []
    t = WALL_THICKNESS
    for (axis, coord), spans in sorted(lines.items()):
        spans.sort()
        merged: list[list[float]] = []
        for lo, hi in spans:
            if merged and lo <= merged[-1][1] + 1e-6:
                merged[-1][1] = max(merged[-1][1], hi)
            else:
                merged.append([lo, hi])
        gaps = sorted(
            (d.centre - DOOR_WIDTH / 2, d.centre + DOOR_WIDTH / 2)
            for d in doors
            if d.axis == axis and np.isclose(d.coord, coord)
        )
        for lo, hi in merged:
            pieces, start = [], lo - t / 2
            for g0, g1 in gaps:
                if lo < g0 < hi:
                    pieces.append((start, g0))
                    start = g1
            pieces.append((start, hi + t / 2))
            segments = [(a, b, 0.0, CEILING_HEIGHT) for a, b in pieces]
            segments += [(g0, g1, DOOR_HEIGHT, CEILING_HEIGHT) for g0, g1 in gaps if lo < g0 < hi]
            for a, b, z0, z1 in segments:
                mid, length = (a + b) / 2, b - a
                if axis == 0:
                    centre, size = (mid, coord, (z0 + z1) / 2), (length, t, z1 - z0)
                else:
                    centre, size = (coord, mid, (z0 + z1) / 2), (t, length, z1 - z0)
                parts.append(Part("box", centre, size, colour))
    return parts


def _slabs(rect: np.ndarray) -> dict[str, list[Part]]:
    floors, ceilings = [], []
    for x0, y0, x1, y1 in rect:
        c = ((x0 + x1) / 2, (y0 + y1) / 2)
        floors.append(
            Part("box", (c[0], c[1], -0.025), (x1 - x0, y1 - y0, 0.05), STRUCTURE_COLOURS["floor"])
        )
        ceilings.append(
            Part(
                "box",
                (c[0], c[1], CEILING_HEIGHT + 0.025),
                (x1 - x0, y1 - y0, 0.05),
                STRUCTURE_COLOURS["ceiling"],
            )
        )
    return {"floor": floors, "ceiling": ceilings}


def _nav_mask(rect: np.ndarray, doors: list[Door]) -> tuple[np.ndarray, np.ndarray]:
    """Cells (NAV_CELL m) of the navigation zone: centre disks and corridors to the doors."""
    origin = rect[:, :2].min(axis=0) - 0.5
    extent = rect[:, 2:].max(axis=0) + 0.5 - origin
    nx, ny = (np.ceil(extent / NAV_CELL)).astype(int)
    gx, gy = np.meshgrid(
        origin[0] + (np.arange(nx) + 0.5) * NAV_CELL,
        origin[1] + (np.arange(ny) + 0.5) * NAV_CELL,
        indexing="ij",
    )
    pts = np.stack([gx, gy], axis=-1)
    mask = np.zeros((nx, ny), bool)
    centres = (rect[:, :2] + rect[:, 2:]) / 2
    for c in centres:
        mask |= np.linalg.norm(pts - c, axis=-1) <= NAV_RADIUS
    for d in doors:
        a, b = d.points(0.6)
        ca, cb = centres[d.rooms[0]], centres[d.rooms[1]]
        # each door point belongs to the room on its side
        if np.linalg.norm(a - ca) > np.linalg.norm(a - cb):
            a, b = b, a
        for p, q in ((ca, a), (a, b), (b, cb)):
            mask |= _segment_distance(pts, p, q) <= CORRIDOR_HALF_WIDTH
    return mask, origin


def _segment_distance(pts: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    ab = b - a
    t = np.clip(((pts - a) @ ab) / max(float(ab @ ab), 1e-12), 0, 1)
    return np.linalg.norm(pts - (a + t[..., None] * ab), axis=-1)


# ----------------------------------------------------------------------------- placement
class _Placer:
    """Accepts or rejects candidate objects against what is already in the scene."""

    def __init__(self, scene_walls: list[Part], nav: np.ndarray, nav_origin: np.ndarray) -> None:
        self.objects: list[PlacedObject] = []
        self.boxes = np.zeros((0, 2, 3))
        self.box_owner = np.zeros(0, int)
        self.nav = nav
        self.nav_origin = nav_origin

    def free(
        self, parts: list[Part], interior: np.ndarray, support_id: int, on_floor: bool
    ) -> bool:
        boxes = np.stack([np.stack(p.bbox) for p in parts])
        lo, hi = boxes[:, 0].min(0), boxes[:, 1].max(0)
        if np.any(lo[:2] < interior[:2] - 1e-9) or np.any(hi[:2] > interior[2:] + 1e-9):
            return False
        if on_floor and self._covers_nav(lo, hi):
            return False
        if len(self.boxes):
            margin = np.where(self.box_owner == support_id, -1e-6, PLACE_MARGIN)[:, None, None]
            a = boxes[None, :, :, :]
            b = self.boxes[:, None, :, :]
            overlap = np.all(
                (a[..., 0, :] < b[..., 1, :] + margin) & (b[..., 0, :] < a[..., 1, :] + margin),
                axis=-1,
            )
            if overlap.any():
                return False
        return True

    def _covers_nav(self, lo: np.ndarray, hi: np.ndarray) -> bool:
        i0, j0 = np.floor((lo[:2] - self.nav_origin) / NAV_CELL).astype(int)
        i1, j1 = np.ceil((hi[:2] - self.nav_origin) / NAV_CELL).astype(int)
        return bool(self.nav[max(i0, 0) : i1, max(j0, 0) : j1].any())

    def add(self, obj: PlacedObject) -> None:
        self.objects.append(obj)
        self.boxes = np.concatenate([self.boxes, obj.part_boxes])
        self.box_owner = np.concatenate([self.box_owner, np.full(len(obj.parts), obj.instance_id)])


def _world(built: Built, turns: int, offset: np.ndarray) -> tuple[list[Part], tuple | None]:
    parts = [rotate_part(p, turns, offset) for p in built.parts]
    surface = None
    if built.surface is not None:
        x0, x1, y0, y1, z = built.surface
        corners = np.array([[x0, y0], [x1, y1]])
        for _ in range(turns % 4):
            corners = np.stack([-corners[:, 1], corners[:, 0]], axis=1)
        lo, hi = corners.min(0) + offset[:2], corners.max(0) + offset[:2]
        surface = (float(lo[0]), float(hi[0]), float(lo[1]), float(hi[1]), float(z + offset[2]))
    return parts, surface


def _local_bounds(built: Built, turns: int) -> tuple[np.ndarray, np.ndarray]:
    parts = [rotate_part(p, turns, np.zeros(3)) for p in built.parts]
    boxes = np.stack([np.stack(p.bbox) for p in parts])
    return boxes[:, 0].min(0), boxes[:, 1].max(0)


class _RoomFurnisher:
    """Places one room's furniture through a shared :class:`_Placer`."""

    TRIES = 30

    def __init__(
        self,
        placer: _Placer,
        room_id: int,
        rect: np.ndarray,
        doors: list[Door],
        rng: np.random.Generator,
        next_id: list[int],
        kit: _Kit | None = None,
    ) -> None:
        self.kit = kit or _kit(Catalogue.SAMPLE)
        self.placer = placer
        self.room_id = room_id
        self.rect = rect
        h = WALL_THICKNESS / 2
        self.interior = np.array([rect[0] + h, rect[1] + h, rect[2] - h, rect[3] - h])
        self.doors = doors
        self.rng = rng
        self.next_id = next_id

    def _commit(
        self, spec: ClassSpec, parts: list[Part], surface: tuple | None, support_id: int = 0
    ) -> PlacedObject:
        obj = PlacedObject(
            self.next_id[0], spec.name, self.room_id, tuple(parts), support_id, surface
        )
        self.next_id[0] += 1
        self.placer.add(obj)
        return obj

    def place_wall(self, spec: ClassSpec) -> PlacedObject | None:
        built, _ = build_instance(spec, self.rng)
        for _ in range(self.TRIES):
            side = int(self.rng.integers(4))  # 0: +y wall, 1: -x, 2: -y, 3: +x; turns = side
            lo, hi = _local_bounds(built, side)
            x0, y0, x1, y1 = self.interior
            gap = 0.01
            if side in (0, 2):
                if hi[0] - lo[0] > x1 - x0:
                    continue
                x = self.rng.uniform(x0 - lo[0], x1 - hi[0])
                y = (y1 - gap - hi[1]) if side == 0 else (y0 + gap - lo[1])
            else:
                if hi[1] - lo[1] > y1 - y0:
                    continue
                y = self.rng.uniform(y0 - lo[1], y1 - hi[1])
                x = (x0 + gap - lo[0]) if side == 1 else (x1 - gap - hi[0])
            parts, surface = _world(built, side, np.array([x, y, 0.0]))
            if self.placer.free(parts, self.interior, 0, True):
                return self._commit(spec, parts, surface)
        return None

    def place_free(self, spec: ClassSpec) -> PlacedObject | None:
        built, _ = build_instance(spec, self.rng)
        for _ in range(self.TRIES):
            turns = int(self.rng.integers(4))
            lo, hi = _local_bounds(built, turns)
            x0, y0, x1, y1 = self.interior + np.array([0.3, 0.3, -0.3, -0.3])
            if hi[0] - lo[0] > x1 - x0 or hi[1] - lo[1] > y1 - y0:
                return None
            x = self.rng.uniform(x0 - lo[0], x1 - hi[0])
            y = self.rng.uniform(y0 - lo[1], y1 - hi[1])
            parts, surface = _world(built, turns, np.array([x, y, 0.0]))
            if self.placer.free(parts, self.interior, 0, True):
                return self._commit(spec, parts, surface)
        return None

    def place_on(self, spec: ClassSpec) -> PlacedObject | None:
        supports = [  # (object, its support surface)
            (o, o.surface)
            for o in self.placer.objects
            if o.room_id == self.room_id and o.class_name in spec.supports and o.surface is not None
        ]
        if not supports:
            return None
        built, _ = build_instance(spec, self.rng)
        for _ in range(self.TRIES):
            sup, (sx0, sx1, sy0, sy1, z) = supports[int(self.rng.integers(len(supports)))]
            turns = int(self.rng.integers(4))
            lo, hi = _local_bounds(built, turns)
            if hi[0] - lo[0] > sx1 - sx0 or hi[1] - lo[1] > sy1 - sy0:
                continue
            x = self.rng.uniform(sx0 - lo[0], sx1 - hi[0])
            y = self.rng.uniform(sy0 - lo[1], sy1 - hi[1])
            parts, surface = _world(built, turns, np.array([x, y, z]))
            if self.placer.free(parts, self.interior, sup.instance_id, False):
                return self._commit(spec, parts, surface, sup.instance_id)
        return None

    def place_hung(self, spec: ClassSpec) -> PlacedObject | None:
        built, _ = build_instance(spec, self.rng)
        for _ in range(self.TRIES):
            side = int(self.rng.integers(4))
            lo, hi = _local_bounds(built, side)
            x0, y0, x1, y1 = self.interior
            z = self.rng.uniform(*spec.hang_height)
            if side in (0, 2):
                x = self.rng.uniform(x0 + 0.1 - lo[0], x1 - 0.1 - hi[0])
                y = (y1 - hi[1]) if side == 0 else (y0 - lo[1])
            else:
                y = self.rng.uniform(y0 + 0.1 - lo[1], y1 - 0.1 - hi[1])
                x = (x0 - lo[0]) if side == 1 else (x1 - hi[0])
            parts, _ = _world(built, side, np.array([x, y, z]))
            if self._clear_of_doors(parts) and self.placer.free(parts, self.interior, 0, False):
                return self._commit(spec, parts, None)
        return None

    def _clear_of_doors(self, parts: list[Part]) -> bool:
        boxes = np.stack([np.stack(p.bbox) for p in parts])
        lo, hi = boxes[:, 0].min(0), boxes[:, 1].max(0)
        for d in self.doors:
            a, _ = d.points(0.0)
            door_lo = a - np.where(
                d.axis == 0, [DOOR_WIDTH / 2 + 0.1, 0.2], [0.2, DOOR_WIDTH / 2 + 0.1]
            )
            door_hi = a + np.where(
                d.axis == 0, [DOOR_WIDTH / 2 + 0.1, 0.2], [0.2, DOOR_WIDTH / 2 + 0.1]
            )
            if np.all(lo[:2] < door_hi) and np.all(door_lo < hi[:2]):
                return False
        return True

    def place_companions(
        self, parent: PlacedObject, spec_name: str, count: int, sides: tuple[int, ...]
    ) -> None:
        spec = self.kit.classes[spec_name]
        lo, hi = parent.bbox
        centre = (lo + hi) / 2
        for _ in range(count):
            built, _ = build_instance(spec, self.rng)
            for _ in range(6):
                side = sides[int(self.rng.integers(len(sides)))]
                # world direction from the parent centre to the chair: -y, +y, -x, +x
                direction = [(0, -1), (0, 1), (-1, 0), (1, 0)][side]
                # chair front (-y local) must face the parent: turns so that -y local -> -direction
                turns = {(0, -1): 0, (0, 1): 2, (-1, 0): 3, (1, 0): 1}[direction]
                clo, chi = _local_bounds(built, turns)
                if direction[0] == 0:
                    x = (
                        self.rng.uniform(lo[0] + 0.2 - clo[0], hi[0] - 0.2 - chi[0])
                        if hi[0] - lo[0] > chi[0] - clo[0] + 0.4
                        else centre[0]
                    )
                    y = lo[1] - 0.08 - chi[1] if direction[1] < 0 else hi[1] + 0.08 - clo[1]
                else:
                    y = (
                        self.rng.uniform(lo[1] + 0.1 - clo[1], hi[1] - 0.1 - chi[1])
                        if hi[1] - lo[1] > chi[1] - clo[1] + 0.2
                        else centre[1]
                    )
                    x = lo[0] - 0.08 - chi[0] if direction[0] < 0 else hi[0] + 0.08 - clo[0]
                parts, _ = _world(built, turns, np.array([x, y, 0.0]))
                if self.placer.free(parts, self.interior, 0, True):
                    self._commit(spec, parts, None)
                    break

    def place(self, spec: ClassSpec) -> PlacedObject | None:
        """Place one instance of ``spec`` where its kind goes; None if no room was found."""
        return {
            "wall": self.place_wall,
            "free": self.place_free,
            "on": self.place_on,
            "hung": self.place_hung,
        }[spec.placement](spec)

    def furnish(self, room_type: str, clutter: float) -> None:
        kit = self.kit
        for name, prob, (cmin, cmax) in kit.room_types[room_type].contents:
            if prob < 1.0 and self.rng.random() >= prob * clutter:
                continue
            spec = kit.classes[name]
            for _ in range(int(self.rng.integers(cmin, cmax + 1))):
                placed = self.place(spec)
                if placed is not None and name in kit.companions:
                    comp, (kmin, kmax), sides = kit.companions[name]
                    self.place_companions(
                        placed, comp, int(self.rng.integers(kmin, kmax + 1)), sides
                    )

    FILL_FAILURES = 25
    """Consecutive failed placements after which a room counts as full."""

    def fill(self, room_type: str, target: int, sibling_weight: float) -> None:
        """Add small, hung and floor objects until the room holds ``target`` instances.

        Classes are drawn from the room kind's fill list with weights that grow by
        ``sibling_weight`` times for a class already drawn, so rooms get same-class siblings
        as Matterport3D rooms do (several pillows, pictures, books)."""
        names = self.kit.fill.get(room_type, ())
        if not names or target <= 0:
            return
        weights = np.ones(len(names))
        failures = 0
        target = int(self.rng.integers(round(0.6 * target), round(1.4 * target) + 1))
        while self._count() < target and failures < self.FILL_FAILURES:
            k = int(self.rng.choice(len(names), p=weights / weights.sum()))
            if self.place(self.kit.classes[names[k]]) is None:
                failures += 1
                continue
            failures = 0
            weights[k] = max(weights[k], sibling_weight)

    def _count(self) -> int:
        return sum(o.room_id == self.room_id for o in self.placer.objects)


ROOM_ORDER = ("living room", "kitchen", "bedroom", "bathroom", "office", "dining room")


def generate_scene(config: SceneConfig | None = None) -> Scene:
    """Generate the scene of ``config`` (same config, same scene, bit for bit)."""
    from care_maps.core.errors import WorldError

    config = config or SceneConfig()
    rng = np.random.default_rng([config.seed, 1])
    n = config.num_rooms if config.num_rooms is not None else int(rng.integers(2, 6))
    if not 1 <= n <= 6:
        msg = f"num_rooms={n}: the sample world makes 1 to 6 rooms"
        raise WorldError(msg)
    if config.room_types is not None:
        unknown = [t for t in config.room_types if t not in ROOM_TYPES]
        if unknown or len(config.room_types) != n:
            msg = f"room_types={config.room_types}: give {n} names from {', '.join(ROOM_TYPES)}"
            raise WorldError(msg)
        types = list(config.room_types)
    else:
        first = list(ROOM_ORDER[:n]) if n <= 4 else list(ROOM_ORDER[:4])
        rest = list(rng.choice(ROOM_ORDER, n - len(first)))
        types = [str(t) for t in rng.permutation(first + rest)]
    rect, doors = _floor_plan(n, rng)
    walls = _walls(rect, doors)
    nav, nav_origin = _nav_mask(rect, doors)
    placer = _Placer(walls, nav, nav_origin)
    next_id = [1]
    kit = _kit(config.catalogue)
    for i in range(n):
        room_doors = [d for d in doors if i in d.rooms]
        furnisher = _RoomFurnisher(placer, i, rect[i], room_doors, rng, next_id, kit)
        furnisher.furnish(types[i], config.clutter)
        furnisher.fill(types[i], config.instances_per_room, config.sibling_weight)
    rooms = [
        Room(i, types[i], np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]], np.float64))
        for i, (x0, y0, x1, y1) in enumerate(rect)
    ]
    return Scene(
        config=config,
        rooms=rooms,
        room_rects=rect,
        doors=doors,
        structure={"wall": walls, **_slabs(rect)},
        objects=placer.objects,
        nav_mask=nav,
        nav_origin=nav_origin,
    )
