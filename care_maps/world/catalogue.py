"""The object catalogue of the sample world: classes named as Matterport raw categories.

Each :class:`ClassSpec` says how big an instance may be, where it goes (against a wall, free
in the room, on top of other furniture, or hung on a wall), what it may stand on, and how
to build it from boxes and cylinders. Local frame of a built object: footprint centred at
the origin, z from 0 up, the *front* facing -y and the back at +y (the side put against
a wall).

The names are exact ``raw_category`` values of Matterport3D's
``category_mapping.tsv`` (tested), so the sample world's vocabulary is the paper's.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal

import numpy as np

from care_maps.world.meshes import Part

__all__ = [
    "CATALOGUE",
    "CLASS_NAMES",
    "COMPANIONS",
    "ROOM_TYPES",
    "STRUCTURE_CLASSES",
    "Built",
    "ClassSpec",
    "RoomType",
    "build_instance",
]

RGB = tuple[float, float, float]
Surface = tuple[float, float, float, float, float]
"""A horizontal support surface in the local frame: (xmin, xmax, ymin, ymax, z)."""


@dataclass(frozen=True)
class Built:
    """One built instance in its local frame."""

    parts: list[Part]
    surface: Surface | None
    """Where other objects may rest on it, if anywhere."""


@dataclass(frozen=True)
class ClassSpec:
    """How to make instances of one class."""

    name: str
    size_min: tuple[float, float, float]
    """Smallest (width x, depth y, height z) in metres."""
    size_max: tuple[float, float, float]
    placement: Literal["wall", "free", "on", "hung"]
    """wall: on the floor, back to a wall; free: on the floor anywhere; on: on a support;
    hung: on a wall at a height."""
    build: Callable[[float, float, float, dict[str, RGB]], Built]
    palette: tuple[RGB, ...]
    """Base colours of the main material; an instance takes one and varies it."""
    supports: tuple[str, ...] = ()
    """For ``on``: classes it may rest on."""
    hang_height: tuple[float, float] = (1.2, 1.7)
    """For ``hung``: range of the height of its lowest point."""


# ----------------------------------------------------------------------------- colours
WOOD: tuple[RGB, ...] = (
    (0.55, 0.38, 0.22),
    (0.72, 0.56, 0.38),
    (0.38, 0.25, 0.15),
    (0.83, 0.72, 0.56),
)
FABRIC: tuple[RGB, ...] = (
    (0.25, 0.35, 0.55),
    (0.6, 0.2, 0.2),
    (0.5, 0.5, 0.48),
    (0.3, 0.45, 0.3),
    (0.75, 0.68, 0.55),
)
WHITE: tuple[RGB, ...] = ((0.93, 0.93, 0.91), (0.88, 0.9, 0.93))
DARK: tuple[RGB, ...] = ((0.1, 0.1, 0.11), (0.2, 0.2, 0.22))
METAL: tuple[RGB, ...] = ((0.72, 0.72, 0.75), (0.55, 0.56, 0.6))
BRIGHT: tuple[RGB, ...] = (
    (0.85, 0.3, 0.2),
    (0.2, 0.5, 0.8),
    (0.9, 0.75, 0.2),
    (0.4, 0.7, 0.5),
    (0.7, 0.4, 0.7),
)
GREEN: tuple[RGB, ...] = ((0.2, 0.5, 0.2), (0.3, 0.6, 0.25), (0.15, 0.4, 0.25))
POT = (0.6, 0.32, 0.2)


def _b(x: float, y: float, z0: float, sx: float, sy: float, sz: float, col: RGB) -> Part:
    """A box with its bottom at ``z0``."""
    return Part("box", (x, y, z0 + sz / 2), (sx, sy, sz), col)


def _c(x: float, y: float, z0: float, dx: float, dy: float, sz: float, col: RGB) -> Part:
    """An upright cylinder with its bottom at ``z0`` (diameters dx, dy)."""
    return Part("cylinder", (x, y, z0 + sz / 2), (dx, dy, sz), col)


def _corners(hx: float, hy: float) -> list[tuple[float, float]]:
    """The four (x, y) points at +-hx, +-hy (legs, feet, burners)."""
    return [(sx * hx, sy * hy) for sx in (-1, 1) for sy in (-1, 1)]


def _top(w: float, d: float, h: float, inset: float = 0.02) -> Surface:
    return (-w / 2 + inset, w / 2 - inset, -d / 2 + inset, d / 2 - inset, h)


# ----------------------------------------------------------------------------- builders
def table(w: float, d: float, h: float, c: dict[str, RGB]) -> Built:
    t, leg = 0.04, 0.06
    parts = [_b(0, 0, h - t, w, d, t, c["main"])]
    parts += [
        _b(x, y, 0, leg, leg, h - t, c["accent"]) for x, y in _corners(w / 2 - leg, d / 2 - leg)
    ]
    return Built(parts, _top(w, d, h))


def round_table(w: float, d: float, h: float, c: dict[str, RGB]) -> Built:
    t = 0.04
    parts = [
        _c(0, 0, h - t, w, d, t, c["main"]),
        _c(0, 0, 0.03, 0.1, 0.1, h - t - 0.03, c["accent"]),
        _c(0, 0, 0, 0.5 * w, 0.5 * d, 0.03, c["accent"]),
    ]
    r = 0.33
    return Built(parts, (-w * r, w * r, -d * r, d * r, h))


def desk(w: float, d: float, h: float, c: dict[str, RGB]) -> Built:
    t, leg, unit = 0.04, 0.05, min(0.42, w / 3)
    ux = w / 2 - unit / 2 - 0.01
    parts = [
        _b(0, 0, h - t, w, d, t, c["main"]),
        _b(-(w / 2 - leg), -(d / 2 - leg), 0, leg, leg, h - t, c["accent"]),
        _b(-(w / 2 - leg), d / 2 - leg, 0, leg, leg, h - t, c["accent"]),
        _b(ux, 0, 0, unit, d - 0.04, h - t, c["main"]),
    ]
    for k in range(3):
        z = 0.06 + k * (h - 0.12) / 3
        parts.append(_b(ux, -d / 2 + 0.005, z + 0.05, unit - 0.06, 0.03, 0.03, c["metal"]))
    return Built(parts, _top(w, d, h))


def chair(w: float, d: float, h: float, c: dict[str, RGB]) -> Built:
    hs, leg = 0.46, 0.04
    parts = [
        _b(0, 0, hs - 0.05, w, d, 0.05, c["main"]),
        _b(0, d / 2 - 0.025, hs, w, 0.05, h - hs, c["main"]),
    ]
    parts += [
        _b(x, y, 0, leg, leg, hs - 0.05, c["accent"]) for x, y in _corners(w / 2 - leg, d / 2 - leg)
    ]
    return Built(parts, None)


def office_chair(w: float, d: float, h: float, c: dict[str, RGB]) -> Built:
    hs = 0.48
    parts = [
        _b(0, 0, 0, w, 0.06, 0.04, c["metal"]),
        _b(0, 0, 0, 0.06, d, 0.04, c["metal"]),
        _c(0, 0, 0.04, 0.06, 0.06, hs - 0.12, c["metal"]),
        _b(0, -0.03, hs - 0.08, w * 0.9, d * 0.8, 0.08, c["main"]),
        _b(0, d / 2 - 0.04, hs, w * 0.85, 0.06, h - hs, c["main"]),
    ]
    return Built(parts, None)


def armchair(w: float, d: float, h: float, c: dict[str, RGB]) -> Built:
    arm, back, seat = 0.16, 0.2, 0.42
    parts = [
        _b(0, -back / 2, 0.08, w - 2 * arm, d - back, seat - 0.08, c["main"]),
        _b(0, d / 2 - back / 2, 0.08, w, back, h - 0.08, c["main"]),
        _b(-(w / 2 - arm / 2), -back / 2, 0.08, arm, d - back, 0.62 - 0.08, c["main"]),
        _b(w / 2 - arm / 2, -back / 2, 0.08, arm, d - back, 0.62 - 0.08, c["main"]),
    ]
    parts += [
        _c(x, y, 0, 0.05, 0.05, 0.08, c["accent"]) for x, y in _corners(w / 2 - 0.05, d / 2 - 0.05)
    ]
    return Built(parts, (-(w / 2 - arm), w / 2 - arm, -d / 2 + 0.02, d / 2 - back, seat))


def stool(w: float, d: float, h: float, c: dict[str, RGB]) -> Built:
    parts = [_c(0, 0, h - 0.05, w, d, 0.05, c["main"])]
    for a in range(3):
        ang = 2 * np.pi * a / 3
        parts.append(
            _c(0.3 * w * np.cos(ang), 0.3 * d * np.sin(ang), 0, 0.04, 0.04, h - 0.05, c["accent"])
        )
    return Built(parts, None)


def ottoman(w: float, d: float, h: float, c: dict[str, RGB]) -> Built:
    parts = [
        _b(0, 0, 0.05, w, d, h - 0.05, c["main"]),
        _b(0, 0, 0, w - 0.1, d - 0.1, 0.05, c["accent"]),
    ]
    return Built(parts, None)


def bench(w: float, d: float, h: float, c: dict[str, RGB]) -> Built:
    parts = [
        _b(0, 0, h - 0.05, w, d, 0.05, c["main"]),
        _b(-(w / 2 - 0.1), 0, 0, 0.05, d - 0.04, h - 0.05, c["accent"]),
        _b(w / 2 - 0.1, 0, 0, 0.05, d - 0.04, h - 0.05, c["accent"]),
    ]
    return Built(parts, None)


def bed(w: float, d: float, h: float, c: dict[str, RGB]) -> Built:
    head = 0.08
    parts = [
        _b(0, -head / 2, 0.1, w, d - head, 0.25, c["accent"]),
        _b(0, -head / 2, 0.35, w - 0.06, d - head - 0.06, 0.2, c["bedding"]),
        _b(0, d / 2 - head / 2, 0, w, head, h, c["accent"]),
    ]
    parts += [
        _b(sx * (w / 2 - 0.05), -d / 2 + 0.05, 0, 0.06, 0.06, 0.1, c["accent"]) for sx in (-1, 1)
    ]
    surface = (-w / 2 + 0.08, w / 2 - 0.08, d / 2 - head - 0.6, d / 2 - head - 0.05, 0.55)
    return Built(parts, surface)


def sofa(w: float, d: float, h: float, c: dict[str, RGB]) -> Built:
    return armchair(w, d, h, c)


def cabinet(w: float, d: float, h: float, c: dict[str, RGB]) -> Built:
    """Body on a plinth with doors (or drawers when low and wide) and handles on the front."""
    plinth = 0.06
    parts = [
        _b(0, 0, 0, w - 0.04, d - 0.04, plinth, c["accent"]),
        _b(0, 0, plinth, w, d, h - plinth, c["main"]),
    ]
    drawers = h < 1.0 and w > 0.7
    n_doors = 1 if drawers else max(1, round(w / 0.5))
    rows = 3 if drawers else 1
    dw = w / n_doors
    dh = (h - plinth) / rows
    for i in range(n_doors):
        x = -w / 2 + dw * (i + 0.5)
        for r in range(rows):
            z = plinth + r * dh
            parts.append(_b(x, -d / 2 - 0.01, z + 0.01, dw - 0.02, 0.02, dh - 0.02, c["door"]))
            if drawers:
                parts.append(_b(x, -d / 2 - 0.03, z + dh / 2, 0.12, 0.02, 0.02, c["metal"]))
            else:
                hx = x + (dw / 2 - 0.06) * (1 if i % 2 == 0 else -1)
                parts.append(_b(hx, -d / 2 - 0.03, z + dh / 2, 0.02, 0.02, 0.12, c["metal"]))
    return Built(parts, _top(w, d, h))


def kitchen_cabinet(w: float, d: float, h: float, c: dict[str, RGB]) -> Built:
    built = cabinet(w, d, h - 0.04, c)
    parts = [*built.parts, _b(0, -0.01, h - 0.04, w, d + 0.02, 0.04, c["counter"])]
    return Built(parts, _top(w, d, h))


def wardrobe(w: float, d: float, h: float, c: dict[str, RGB]) -> Built:
    return Built(cabinet(w, d, h, c).parts, None)


def refrigerator(w: float, d: float, h: float, c: dict[str, RGB]) -> Built:
    split = 0.62 * h
    parts = [
        _b(0, 0, 0, w, d, h, c["main"]),
        _b(0, -d / 2 - 0.01, 0.02, w - 0.02, 0.02, split - 0.03, c["main"]),
        _b(0, -d / 2 - 0.01, split + 0.01, w - 0.02, 0.02, h - split - 0.03, c["main"]),
        _b(w / 2 - 0.08, -d / 2 - 0.04, split - 0.45, 0.03, 0.04, 0.35, c["metal"]),
        _b(w / 2 - 0.08, -d / 2 - 0.04, split + 0.08, 0.03, 0.04, 0.3, c["metal"]),
    ]
    return Built(parts, None)


def stove(w: float, d: float, h: float, c: dict[str, RGB]) -> Built:
    parts = [
        _b(0, 0, 0, w, d, h - 0.1, c["main"]),
        _b(0, -d / 2 - 0.01, 0.1, w - 0.1, 0.02, h - 0.35, c["dark"]),
        _b(0, d / 2 - 0.03, h - 0.1, w, 0.06, 0.1, c["main"]),
    ]
    parts += [
        _c(x, y - 0.03, h - 0.1, 0.18, 0.18, 0.02, c["dark"]) for x, y in _corners(w / 4, d / 5)
    ]
    return Built(parts, None)


def washing_machine(w: float, d: float, h: float, c: dict[str, RGB]) -> Built:
    parts = [
        _b(0, 0, 0, w, d, h, c["main"]),
        Part("cylinder", (0, -d / 2 - 0.02, 0.42 * h), (0.6 * w, 0.04, 0.6 * w), c["dark"], axis=1),
        _b(0, -d / 2 - 0.01, h - 0.12, w - 0.04, 0.02, 0.1, c["metal"]),
    ]
    return Built(parts, _top(w, d, h))


def microwave(w: float, d: float, h: float, c: dict[str, RGB]) -> Built:
    parts = [
        _b(0, 0, 0, w, d, h, c["main"]),
        _b(-0.08 * w, -d / 2 - 0.005, 0.03, 0.65 * w, 0.01, h - 0.06, c["dark"]),
    ]
    return Built(parts, None)


def shelf(w: float, d: float, h: float, c: dict[str, RGB]) -> Built:
    t = 0.025
    parts = [
        _b(-(w / 2 - t / 2), 0, 0, t, d, h, c["main"]),
        _b(w / 2 - t / 2, 0, 0, t, d, h, c["main"]),
        _b(0, d / 2 - 0.01, 0, w - 2 * t, 0.02, h, c["accent"]),
    ]
    n = max(2, round(h / 0.38))
    for k in range(n + 1):
        z = min(k * h / n, h - t)
        parts.append(_b(0, -0.01, z, w - 2 * t, d - 0.02, t, c["main"]))
    return Built(parts, _top(w, d, h) if h < 1.3 else None)


def toilet(w: float, d: float, h: float, c: dict[str, RGB]) -> Built:
    parts = [
        _b(0, -0.02, 0, 0.24, 0.36, 0.3, c["main"]),
        _c(0, -d / 2 + 0.24, 0.3, w * 0.95, 0.46, 0.12, c["main"]),
        _b(0, d / 2 - 0.1, 0.3, w, 0.2, h - 0.3, c["main"]),
    ]
    return Built(parts, None)


def sink(w: float, d: float, h: float, c: dict[str, RGB]) -> Built:
    base = cabinet(w, d, h - 0.12, c)
    parts = [
        *base.parts,
        _b(0, -0.01, h - 0.12, w, d + 0.02, 0.12, c["basin"]),
        _c(0, d / 2 - 0.08, h, 0.04, 0.04, 0.2, c["metal"]),
        _b(0, d / 2 - 0.14, h + 0.14, 0.03, 0.12, 0.03, c["metal"]),
    ]
    return Built(parts, None)


def bathtub(w: float, d: float, h: float, c: dict[str, RGB]) -> Built:
    t = 0.08
    parts = [
        _b(0, 0, 0, w, d, 0.12, c["main"]),
        _b(0, -(d / 2 - t / 2), 0.12, w, t, h - 0.12, c["main"]),
        _b(0, d / 2 - t / 2, 0.12, w, t, h - 0.12, c["main"]),
        _b(-(w / 2 - t / 2), 0, 0.12, t, d - 2 * t, h - 0.12, c["main"]),
        _b(w / 2 - t / 2, 0, 0.12, t, d - 2 * t, h - 0.12, c["main"]),
    ]
    return Built(parts, None)


def lamp(w: float, d: float, h: float, c: dict[str, RGB]) -> Built:
    shade = 0.35 * h
    parts = [
        _c(0, 0, 0, 0.6 * w, 0.6 * d, 0.03, c["accent"]),
        _c(0, 0, 0.03, 0.03, 0.03, h - shade - 0.03, c["metal"]),
        _c(0, 0, h - shade, w, d, shade, c["main"]),
    ]
    return Built(parts, None)


def screen(w: float, d: float, h: float, c: dict[str, RGB]) -> Built:
    """tv / monitor: a thin panel on a neck and a foot."""
    foot = 0.02
    neck = 0.12 * h
    panel = h - foot - neck
    parts = [
        _b(0, 0, 0, 0.35 * w, d, foot, c["dark"]),
        _b(0, 0, foot, 0.06, 0.04, neck, c["dark"]),
        _b(0, 0, foot + neck, w, 0.05, panel, c["dark"]),
        _b(0, -0.03, foot + neck + 0.02, w - 0.04, 0.01, panel - 0.04, c["screen"]),
    ]
    return Built(parts, None)


def laptop(w: float, d: float, h: float, c: dict[str, RGB]) -> Built:
    parts = [
        _b(0, 0, 0, w, d, 0.02, c["main"]),
        _b(0, d / 2 - 0.006, 0.02, w, 0.012, h - 0.02, c["main"]),
    ]
    return Built(parts, None)


def plant(w: float, d: float, h: float, c: dict[str, RGB]) -> Built:
    pot = 0.3 * h
    parts = [_c(0, 0, 0, 0.6 * w, 0.6 * d, pot, POT)]
    layers = 3
    for k in range(layers):
        s = 1.0 - 0.28 * k
        z = pot + k * (h - pot) / layers
        parts.append(_c(0, 0, z, s * w, s * d, (h - pot) / layers, c["main"]))
    return Built(parts, None)


def vase(w: float, d: float, h: float, c: dict[str, RGB]) -> Built:
    parts = [
        _c(0, 0, 0, w, d, 0.7 * h, c["main"]),
        _c(0, 0, 0.7 * h, 0.5 * w, 0.5 * d, 0.3 * h, c["main"]),
    ]
    return Built(parts, None)


def bottle(w: float, d: float, h: float, c: dict[str, RGB]) -> Built:
    parts = [
        _c(0, 0, 0, w, d, 0.65 * h, c["main"]),
        _c(0, 0, 0.65 * h, 0.35 * w, 0.35 * d, 0.35 * h, c["main"]),
    ]
    return Built(parts, None)


def cylinder(w: float, d: float, h: float, c: dict[str, RGB]) -> Built:
    return Built([_c(0, 0, 0, w, d, h, c["main"])], None)


def trash_can(w: float, d: float, h: float, c: dict[str, RGB]) -> Built:
    parts = [
        _c(0, 0, 0, w * 0.94, d * 0.94, h - 0.04, c["main"]),
        _c(0, 0, h - 0.04, w, d, 0.04, c["accent"]),
    ]
    return Built(parts, None)


def block(w: float, d: float, h: float, c: dict[str, RGB]) -> Built:
    return Built([_b(0, 0, 0, w, d, h, c["main"])], None)


def book(w: float, d: float, h: float, c: dict[str, RGB]) -> Built:
    parts = [
        _b(0, 0, 0, w, d, h, c["main"]),
        _b(0.005, 0, 0.005, w - 0.01, d + 0.004, h - 0.01, WHITE[0]),
    ]
    return Built(parts, None)


def printer(w: float, d: float, h: float, c: dict[str, RGB]) -> Built:
    parts = [
        _b(0, 0.03, 0, w, d - 0.06, h, c["main"]),
        _b(0, -d / 2 + 0.03, 0.4 * h, 0.7 * w, 0.06, 0.02, c["dark"]),
    ]
    return Built(parts, None)


def piano(w: float, d: float, h: float, c: dict[str, RGB]) -> Built:
    parts = [
        _b(0, 0.12, 0, w, d - 0.24, h, c["main"]),
        _b(0, -d / 2 + 0.12, 0.66, w - 0.1, 0.24, 0.06, WHITE[0]),
        _b(-(w / 2 - 0.06), -d / 2 + 0.12, 0, 0.06, 0.06, 0.66, c["main"]),
        _b(w / 2 - 0.06, -d / 2 + 0.12, 0, 0.06, 0.06, 0.66, c["main"]),
    ]
    return Built(parts, (-w / 2 + 0.02, w / 2 - 0.02, 0.02 - d / 2 + 0.24, d / 2 - 0.02, h))


def picture(w: float, d: float, h: float, c: dict[str, RGB]) -> Built:
    parts = [
        _b(0, 0, 0, w, d, h, c["accent"]),
        _b(0, -d / 2 - 0.003, 0.04, w - 0.08, 0.006, h - 0.08, c["main"]),
    ]
    return Built(parts, None)


def clock(w: float, d: float, h: float, c: dict[str, RGB]) -> Built:
    parts = [
        Part("cylinder", (0, 0, h / 2), (w, d, h), c["accent"], axis=1),
        Part("cylinder", (0, -d / 2 - 0.003, h / 2), (0.85 * w, 0.006, 0.85 * h), WHITE[0], axis=1),
    ]
    return Built(parts, None)


def whiteboard(w: float, d: float, h: float, c: dict[str, RGB]) -> Built:
    parts = [
        _b(0, 0, 0.03, w, d, h - 0.03, METAL[0]),
        _b(0, -d / 2 - 0.003, 0.05, w - 0.04, 0.006, h - 0.07, WHITE[0]),
        _b(0, -0.02, 0, 0.6 * w, d + 0.04, 0.03, METAL[1]),
    ]
    return Built(parts, None)


_LAMP_ON = ("nightstand", "side table", "desk", "dresser", "cabinet")
_VASE_ON = (
    "table",
    "coffee table",
    "dining table",
    "dresser",
    "cabinet",
    "shelf",
    "side table",
    "piano",
)

CATALOGUE: dict[str, ClassSpec] = {
    s.name: s
    for s in [
        ClassSpec("bed", (1.0, 2.0, 0.8), (1.7, 2.2, 1.1), "wall", bed, WOOD),
        ClassSpec("nightstand", (0.4, 0.35, 0.45), (0.55, 0.45, 0.6), "wall", cabinet, WOOD + WHITE),
        ClassSpec("dresser", (0.9, 0.45, 0.75), (1.4, 0.55, 0.95), "wall", cabinet, WOOD + WHITE),
        ClassSpec("wardrobe", (1.0, 0.55, 1.9), (1.6, 0.62, 2.2), "wall", wardrobe, WOOD + WHITE),
        ClassSpec("cabinet", (0.6, 0.4, 0.7), (1.2, 0.5, 1.1), "wall", cabinet, WOOD + WHITE + DARK),
        ClassSpec("kitchen cabinet", (0.6, 0.58, 0.88), (1.2, 0.62, 0.92), "wall", kitchen_cabinet, WHITE + WOOD),
        ClassSpec("tv stand", (1.0, 0.38, 0.45), (1.6, 0.48, 0.6), "wall", cabinet, DARK + WOOD),
        ClassSpec("bookshelf", (0.7, 0.28, 1.6), (1.1, 0.35, 2.0), "wall", shelf, WOOD + WHITE),
        ClassSpec("shelf", (0.6, 0.28, 0.7), (1.0, 0.38, 1.1), "wall", shelf, WOOD + WHITE + METAL),
        ClassSpec("desk", (1.0, 0.55, 0.72), (1.5, 0.75, 0.78), "wall", desk, WOOD + WHITE),
        ClassSpec("sofa", (1.6, 0.85, 0.8), (2.3, 0.95, 0.95), "wall", sofa, FABRIC),
        ClassSpec("armchair", (0.75, 0.75, 0.8), (0.95, 0.9, 1.0), "free", armchair, FABRIC),
        ClassSpec("table", (0.8, 0.6, 0.72), (1.3, 0.9, 0.78), "free", table, WOOD + WHITE),
        ClassSpec("dining table", (1.3, 0.8, 0.74), (1.9, 1.0, 0.78), "free", table, WOOD),
        ClassSpec("coffee table", (0.8, 0.5, 0.38), (1.2, 0.7, 0.48), "free", table, WOOD + DARK),
        ClassSpec("side table", (0.4, 0.4, 0.5), (0.55, 0.55, 0.65), "free", round_table, WOOD + WHITE),
        ClassSpec("chair", (0.42, 0.42, 0.85), (0.5, 0.5, 1.0), "free", chair, WOOD + DARK),
        ClassSpec("dining chair", (0.42, 0.45, 0.9), (0.48, 0.52, 1.05), "free", chair, WOOD + FABRIC),
        ClassSpec("office chair", (0.55, 0.55, 0.95), (0.65, 0.65, 1.15), "free", office_chair, DARK + FABRIC),
        ClassSpec("stool", (0.32, 0.32, 0.45), (0.4, 0.4, 0.7), "free", stool, WOOD + METAL),
        ClassSpec("ottoman", (0.45, 0.45, 0.38), (0.7, 0.6, 0.45), "free", ottoman, FABRIC),
        ClassSpec("bench", (1.0, 0.35, 0.42), (1.5, 0.45, 0.48), "wall", bench, WOOD),
        ClassSpec("toilet", (0.38, 0.65, 0.75), (0.42, 0.72, 0.8), "wall", toilet, WHITE),
        ClassSpec("sink", (0.6, 0.45, 0.85), (0.9, 0.55, 0.9), "wall", sink, WOOD + WHITE),
        ClassSpec("bathtub", (1.5, 0.7, 0.5), (1.7, 0.8, 0.6), "wall", bathtub, WHITE),
        ClassSpec("refrigerator", (0.6, 0.62, 1.7), (0.8, 0.72, 1.95), "wall", refrigerator, WHITE + METAL),
        ClassSpec("stove", (0.6, 0.6, 0.9), (0.76, 0.65, 0.95), "wall", stove, WHITE + METAL),
        ClassSpec("washing machine", (0.6, 0.58, 0.85), (0.62, 0.62, 0.88), "wall", washing_machine, WHITE),
        ClassSpec("piano", (1.3, 0.55, 1.1), (1.5, 0.65, 1.3), "wall", piano, DARK + WOOD),
        ClassSpec("trash can", (0.25, 0.25, 0.35), (0.38, 0.38, 0.65), "wall", trash_can, METAL + DARK + WHITE),
        ClassSpec("plant", (0.35, 0.35, 0.7), (0.6, 0.6, 1.4), "wall", plant, GREEN),
        ClassSpec("floor lamp", (0.35, 0.35, 1.4), (0.45, 0.45, 1.75), "wall", lamp, WHITE + FABRIC),
        ClassSpec("lamp", (0.22, 0.22, 0.35), (0.32, 0.32, 0.55), "on", lamp, WHITE + FABRIC, _LAMP_ON),
        ClassSpec("tv", (0.8, 0.22, 0.5), (1.3, 0.28, 0.8), "on", screen, DARK, ("tv stand", "dresser", "cabinet")),
        ClassSpec("monitor", (0.45, 0.2, 0.35), (0.65, 0.22, 0.48), "on", screen, DARK, ("desk", "table")),
        ClassSpec("laptop", (0.3, 0.22, 0.2), (0.38, 0.26, 0.24), "on", laptop, METAL + DARK, ("desk", "table", "coffee table", "dining table")),
        ClassSpec("microwave", (0.45, 0.35, 0.26), (0.55, 0.4, 0.32), "on", microwave, WHITE + METAL + DARK, ("kitchen cabinet",)),
        ClassSpec("vase", (0.12, 0.12, 0.2), (0.2, 0.2, 0.4), "on", vase, BRIGHT + WHITE, _VASE_ON),
        ClassSpec("bowl", (0.2, 0.2, 0.07), (0.3, 0.3, 0.1), "on", cylinder, BRIGHT + WHITE, ("dining table", "kitchen cabinet", "table", "coffee table")),
        ClassSpec("bottle", (0.07, 0.07, 0.22), (0.09, 0.09, 0.32), "on", bottle, GREEN + BRIGHT, ("kitchen cabinet", "dining table", "table")),
        ClassSpec("book", (0.16, 0.22, 0.03), (0.22, 0.3, 0.06), "on", book, BRIGHT, ("coffee table", "nightstand", "desk", "table", "shelf")),
        ClassSpec("box", (0.2, 0.2, 0.12), (0.4, 0.3, 0.25), "on", block, ((0.7, 0.55, 0.35), *WHITE), ("shelf", "cabinet", "dresser", "desk")),
        ClassSpec("basket", (0.25, 0.25, 0.15), (0.4, 0.4, 0.25), "on", cylinder, WOOD, ("shelf", "dresser", "cabinet", "washing machine")),
        ClassSpec("printer", (0.4, 0.35, 0.2), (0.5, 0.42, 0.28), "on", printer, WHITE + DARK, ("cabinet", "desk")),
        ClassSpec("towel", (0.3, 0.25, 0.06), (0.45, 0.3, 0.1), "on", block, WHITE + BRIGHT, ("cabinet", "washing machine", "shelf")),
        ClassSpec("pillow", (0.5, 0.35, 0.12), (0.65, 0.45, 0.18), "on", block, WHITE + FABRIC, ("bed",)),
        ClassSpec("cushion", (0.35, 0.35, 0.12), (0.45, 0.45, 0.16), "on", block, FABRIC + BRIGHT, ("sofa", "armchair")),
        ClassSpec("picture", (0.4, 0.03, 0.3), (1.0, 0.04, 0.8), "hung", picture, BRIGHT + GREEN, hang_height=(1.2, 1.6)),
        ClassSpec("mirror", (0.4, 0.03, 0.6), (0.8, 0.04, 1.0), "hung", picture, ((0.75, 0.8, 0.85),), hang_height=(1.0, 1.3)),
        ClassSpec("clock", (0.25, 0.04, 0.25), (0.4, 0.05, 0.4), "hung", clock, WHITE, hang_height=(1.6, 1.9)),
        ClassSpec("whiteboard", (0.9, 0.03, 0.6), (1.5, 0.04, 0.9), "hung", whiteboard, WHITE, hang_height=(0.9, 1.1)),
    ]
}  # fmt: skip
"""Every class the sample world can place, by name."""

STRUCTURE_CLASSES = ("wall", "floor", "ceiling")
CLASS_NAMES: tuple[str, ...] = ("void", *STRUCTURE_CLASSES, *CATALOGUE)
"""Class id -> name, the same for every scene, so datasets share one vocabulary."""


@dataclass(frozen=True)
class RoomType:
    """What a kind of room holds: ``(class, probability, (min, max) count)`` per class."""

    name: str
    contents: tuple[tuple[str, float, tuple[int, int]], ...]


ROOM_TYPES: dict[str, RoomType] = {
    r.name: r
    for r in [
        RoomType("living room", (
            ("sofa", 1.0, (1, 1)), ("coffee table", 0.9, (1, 1)), ("armchair", 0.8, (1, 2)),
            ("tv stand", 0.8, (1, 1)), ("bookshelf", 0.5, (1, 1)), ("floor lamp", 0.6, (1, 1)),
            ("plant", 0.7, (1, 2)), ("side table", 0.6, (1, 1)), ("ottoman", 0.3, (1, 1)),
            ("piano", 0.15, (1, 1)), ("picture", 0.9, (1, 2)), ("clock", 0.3, (1, 1)),
            ("tv", 0.9, (1, 1)), ("cushion", 0.9, (1, 3)), ("vase", 0.6, (1, 1)),
            ("book", 0.6, (1, 2)), ("lamp", 0.5, (1, 1)),
        )),
        RoomType("bedroom", (
            ("bed", 1.0, (1, 1)), ("nightstand", 0.9, (1, 2)), ("wardrobe", 0.7, (1, 1)),
            ("dresser", 0.5, (1, 1)), ("desk", 0.3, (1, 1)), ("plant", 0.3, (1, 1)),
            ("trash can", 0.3, (1, 1)), ("bench", 0.2, (1, 1)), ("picture", 0.8, (1, 2)),
            ("mirror", 0.4, (1, 1)), ("pillow", 1.0, (1, 3)), ("lamp", 0.9, (1, 2)),
            ("book", 0.5, (1, 2)), ("box", 0.4, (1, 1)), ("laptop", 0.3, (1, 1)), ("tv", 0.2, (1, 1)),
        )),
        RoomType("kitchen", (
            ("kitchen cabinet", 1.0, (2, 4)), ("refrigerator", 1.0, (1, 1)), ("stove", 0.9, (1, 1)),
            ("dining table", 0.5, (1, 1)), ("trash can", 0.8, (1, 1)), ("stool", 0.4, (1, 2)),
            ("clock", 0.4, (1, 1)), ("microwave", 0.8, (1, 1)), ("bowl", 0.7, (1, 2)),
            ("bottle", 0.7, (1, 3)), ("plant", 0.2, (1, 1)),
        )),
        RoomType("bathroom", (
            ("toilet", 1.0, (1, 1)), ("sink", 1.0, (1, 1)), ("bathtub", 0.7, (1, 1)),
            ("cabinet", 0.5, (1, 1)), ("washing machine", 0.4, (1, 1)), ("trash can", 0.6, (1, 1)),
            ("mirror", 0.9, (1, 1)), ("towel", 0.8, (1, 2)), ("basket", 0.4, (1, 1)), ("bottle", 0.4, (1, 2)),
        )),
        RoomType("office", (
            ("desk", 1.0, (1, 2)), ("bookshelf", 0.8, (1, 2)), ("cabinet", 0.6, (1, 1)),
            ("shelf", 0.5, (1, 1)), ("table", 0.5, (1, 1)), ("plant", 0.5, (1, 1)),
            ("trash can", 0.6, (1, 1)), ("whiteboard", 0.6, (1, 1)), ("picture", 0.4, (1, 1)),
            ("monitor", 1.0, (1, 2)), ("laptop", 0.5, (1, 1)), ("printer", 0.5, (1, 1)),
            ("lamp", 0.5, (1, 1)), ("book", 0.7, (1, 3)), ("box", 0.5, (1, 2)),
        )),
        RoomType("dining room", (
            ("dining table", 1.0, (1, 1)), ("cabinet", 0.7, (1, 2)), ("shelf", 0.5, (1, 1)),
            ("plant", 0.6, (1, 2)), ("picture", 0.8, (1, 2)), ("clock", 0.3, (1, 1)),
            ("vase", 0.8, (1, 2)), ("bowl", 0.7, (1, 2)), ("bottle", 0.5, (1, 2)), ("lamp", 0.3, (1, 1)),
        )),
    ]
}  # fmt: skip
"""Room kinds and their furniture; order is placement order (big pieces first)."""

COMPANIONS: dict[str, tuple[str, tuple[int, int], tuple[int, ...]]] = {
    "dining table": ("dining chair", (2, 6), (0, 1, 2, 3)),
    "table": ("chair", (1, 4), (0, 1, 2, 3)),
    "desk": ("office chair", (1, 1), (0,)),
}
"""Parent class -> (companion class, count range, sides it may take: 0 front, 1 back,
2 left, 3 right in the parent's local frame). A chair is placed facing its table."""


def _vary(rgb: RGB, rng: np.random.Generator, amount: float = 0.08) -> RGB:
    scaled = np.asarray(rgb) * (1 + rng.uniform(-amount, amount)) + rng.normal(0, amount / 2, 3)
    out = np.clip(scaled, 0, 1)
    return (float(out[0]), float(out[1]), float(out[2]))


def build_instance(
    spec: ClassSpec, rng: np.random.Generator
) -> tuple[Built, tuple[float, float, float]]:
    """A new instance of ``spec`` with its size and colours drawn from ``rng``."""
    lo = np.asarray(spec.size_min)
    hi = np.asarray(spec.size_max)
    size = lo + (hi - lo) * rng.random(3)
    main = _vary(spec.palette[int(rng.integers(len(spec.palette)))], rng)
    bedding = (*WHITE, *FABRIC)
    colours = {
        "main": main,
        "accent": _vary(tuple(np.asarray(main) * 0.7), rng),
        "door": _vary(tuple(np.clip(np.asarray(main) * 1.08, 0, 1)), rng, 0.03),
        "metal": _vary(METAL[int(rng.integers(len(METAL)))], rng, 0.04),
        "dark": _vary(DARK[0], rng, 0.03),
        "screen": (0.05, 0.07, 0.1),
        "bedding": _vary(bedding[int(rng.integers(len(bedding)))], rng),
        "counter": _vary(((0.3, 0.3, 0.32), (0.85, 0.84, 0.8))[int(rng.integers(2))], rng, 0.04),
        "basin": WHITE[0],
    }
    w, d, h = (float(v) for v in size)
    return spec.build(w, d, h, colours), (w, d, h)
