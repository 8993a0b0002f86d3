"""A Matterport-like catalogue: 180+ classes named as Matterport3D raw categories.

Matterport3D houses are labelled with free-form raw categories (``category_mapping.tsv``,
1659 of them): a room holds two dozen objects, many of one class ("pillow" x 4, "picture"
x 3) and many of classes whose names are near synonyms ("couch" and "sofa", "trash can" and
"trashcan", "painting" and "picture"). That is what makes the first attempt of the paper
succeed only 12% of the time (instances), and what this catalogue reproduces.

Every name below is an exact ``raw_category`` of that file (tested against the file in
``../shared/data/labels``; only the names are used, typed here, so the repository carries
no copy of the data). Classes come in *families*: one builder of boxes and cylinders
(from :mod:`care_maps.world.catalogue`), one placement, one palette, and per class a size range.

Room contents (:data:`MATTERPORT_ROOM_TYPES`) list the large furniture per room kind as in
:data:`care_maps.world.catalogue.ROOM_TYPES`; :data:`MATTERPORT_FILL` lists, per room kind, the small,
hung and floor objects a room is filled with until it holds ``instances_per_room`` objects
(:class:`care_maps.world.scene.SceneConfig`).
"""

from __future__ import annotations

from collections.abc import Callable

from care_maps.world import catalogue as c
from care_maps.world.catalogue import ClassSpec, RoomType

__all__ = [
    "MATTERPORT_CATALOGUE",
    "MATTERPORT_CLASS_NAMES",
    "MATTERPORT_COMPANIONS",
    "MATTERPORT_FILL",
    "MATTERPORT_ROOM_TYPES",
]

Size = tuple[float, float, float]
_Entry = tuple[str, Size, Size]

# ----------------------------------------------------------------------------- families
# (placement, builder, palette, members: (name, size_min, size_max))
_CABINETS: list[_Entry] = [
    ("cabinet", (0.6, 0.4, 0.7), (1.2, 0.5, 1.1)),
    ("kitchen cabinet", (0.6, 0.58, 0.88), (1.2, 0.62, 0.92)),
    ("bath cabinet", (0.5, 0.4, 0.7), (0.9, 0.5, 0.9)),
    ("bathroom cabinet", (0.5, 0.4, 0.7), (0.9, 0.5, 0.9)),
    ("cupboard", (0.6, 0.4, 0.8), (1.1, 0.5, 1.2)),
    ("cabinets", (0.9, 0.45, 0.8), (1.5, 0.55, 1.0)),
    ("nightstand", (0.4, 0.35, 0.45), (0.55, 0.45, 0.6)),
    ("bedside table", (0.4, 0.35, 0.45), (0.55, 0.45, 0.6)),
    ("dresser", (0.9, 0.45, 0.75), (1.4, 0.55, 0.95)),
    ("chest of drawers", (0.8, 0.45, 0.8), (1.1, 0.55, 1.1)),
    ("drawers", (0.5, 0.4, 0.6), (0.9, 0.5, 0.9)),
    ("drawer", (0.4, 0.4, 0.4), (0.7, 0.5, 0.6)),
    ("chest", (0.7, 0.4, 0.45), (1.1, 0.55, 0.6)),
    ("tv stand", (1.0, 0.38, 0.45), (1.6, 0.48, 0.6)),
    ("stand", (0.4, 0.35, 0.5), (0.7, 0.45, 0.8)),
    ("vanity", (0.8, 0.45, 0.8), (1.3, 0.55, 0.9)),
    ("counter", (1.0, 0.55, 0.88), (1.8, 0.65, 0.94)),
    ("kitchen counter", (1.0, 0.58, 0.88), (1.8, 0.65, 0.94)),
    ("bathroom counter", (0.8, 0.5, 0.8), (1.4, 0.6, 0.9)),
    ("countertop", (1.0, 0.55, 0.88), (1.6, 0.65, 0.94)),
    ("display case", (0.6, 0.4, 0.9), (1.0, 0.5, 1.2)),
    ("pedestal", (0.35, 0.35, 0.8), (0.5, 0.5, 1.1)),
]
_TALL: list[_Entry] = [
    ("wardrobe", (1.0, 0.55, 1.9), (1.6, 0.62, 2.2)),
    ("closet", (1.0, 0.55, 1.9), (1.6, 0.62, 2.2)),
    ("locker", (0.4, 0.45, 1.7), (0.6, 0.5, 1.9)),
]
_SHELVES: list[_Entry] = [
    ("bookshelf", (0.7, 0.28, 1.6), (1.1, 0.35, 2.0)),
    ("bookcase", (0.7, 0.28, 1.6), (1.1, 0.35, 2.0)),
    ("shelf", (0.6, 0.28, 0.7), (1.0, 0.38, 1.1)),
    ("shelves", (0.6, 0.28, 0.8), (1.0, 0.38, 1.2)),
    ("shelving", (0.8, 0.35, 1.4), (1.2, 0.45, 1.9)),
    ("storage shelving", (0.8, 0.4, 1.5), (1.2, 0.5, 1.9)),
    ("kitchen shelf", (0.6, 0.28, 0.7), (1.0, 0.35, 1.0)),
    ("rack", (0.5, 0.3, 0.8), (0.9, 0.4, 1.2)),
]
_DESKS: list[_Entry] = [
    ("desk", (1.0, 0.55, 0.72), (1.5, 0.75, 0.78)),
    ("computer desk", (1.0, 0.55, 0.72), (1.4, 0.7, 0.78)),
]
_TABLES: list[_Entry] = [
    ("table", (0.8, 0.6, 0.72), (1.3, 0.9, 0.78)),
    ("dining table", (1.3, 0.8, 0.74), (1.9, 1.0, 0.78)),
    ("coffee table", (0.8, 0.5, 0.38), (1.2, 0.7, 0.48)),
    ("office table", (1.0, 0.6, 0.72), (1.5, 0.8, 0.78)),
    ("kitchen island", (1.2, 0.7, 0.88), (1.8, 0.9, 0.94)),
    ("pool table", (1.8, 1.0, 0.78), (2.2, 1.2, 0.82)),
]
_SMALL_TABLES: list[_Entry] = [
    ("side table", (0.4, 0.4, 0.5), (0.55, 0.55, 0.65)),
    ("end table", (0.4, 0.4, 0.5), (0.6, 0.6, 0.65)),
    ("sidetable", (0.4, 0.4, 0.5), (0.55, 0.55, 0.65)),
    ("round table", (0.6, 0.6, 0.7), (0.9, 0.9, 0.76)),
]
_CHAIRS: list[_Entry] = [
    ("chair", (0.42, 0.42, 0.85), (0.5, 0.5, 1.0)),
    ("dining chair", (0.42, 0.45, 0.9), (0.48, 0.52, 1.05)),
    ("wooden chair", (0.42, 0.42, 0.85), (0.5, 0.5, 1.0)),
    ("highchair", (0.4, 0.4, 0.95), (0.48, 0.48, 1.05)),
]
_SWIVEL: list[_Entry] = [
    ("office chair", (0.55, 0.55, 0.95), (0.65, 0.65, 1.15)),
    ("desk chair", (0.5, 0.5, 0.9), (0.6, 0.6, 1.1)),
    ("swivel chair", (0.55, 0.55, 0.95), (0.65, 0.65, 1.15)),
]
_ARMCHAIRS: list[_Entry] = [
    ("armchair", (0.75, 0.75, 0.8), (0.95, 0.9, 1.0)),
    ("sofa chair", (0.75, 0.75, 0.8), (0.95, 0.9, 1.0)),
    ("easy chair", (0.75, 0.75, 0.8), (0.95, 0.9, 1.0)),
    ("lounge chair", (0.7, 0.8, 0.75), (0.9, 1.0, 0.95)),
]
_SOFAS: list[_Entry] = [
    ("sofa", (1.6, 0.85, 0.8), (2.3, 0.95, 0.95)),
    ("couch", (1.6, 0.85, 0.8), (2.3, 0.95, 0.95)),
]
_STOOLS: list[_Entry] = [
    ("stool", (0.32, 0.32, 0.45), (0.4, 0.4, 0.7)),
    ("seat", (0.35, 0.35, 0.42), (0.45, 0.45, 0.5)),
]
_OTTOMANS: list[_Entry] = [
    ("ottoman", (0.45, 0.45, 0.38), (0.7, 0.6, 0.45)),
    ("footstool", (0.35, 0.3, 0.3), (0.5, 0.4, 0.4)),
    ("footrest", (0.35, 0.3, 0.3), (0.5, 0.4, 0.4)),
]
_BENCHES: list[_Entry] = [
    ("bench", (1.0, 0.35, 0.42), (1.5, 0.45, 0.48)),
    ("pew", (1.2, 0.45, 0.85), (1.6, 0.5, 0.9)),
]
_BEDS: list[_Entry] = [
    ("bed", (1.0, 2.0, 0.8), (1.7, 2.2, 1.1)),
    ("bedframe", (1.0, 2.0, 0.8), (1.6, 2.1, 1.0)),
    ("massage bed", (0.7, 1.9, 0.7), (0.8, 2.0, 0.8)),
]
_TOILETS: list[_Entry] = [
    ("toilet", (0.38, 0.65, 0.75), (0.42, 0.72, 0.8)),
    ("bidet", (0.36, 0.55, 0.4), (0.4, 0.6, 0.45)),
    ("commode", (0.38, 0.65, 0.75), (0.42, 0.72, 0.8)),
]
_SINKS: list[_Entry] = [
    ("sink", (0.6, 0.45, 0.85), (0.9, 0.55, 0.9)),
    ("washbasin", (0.5, 0.4, 0.8), (0.7, 0.5, 0.9)),
    ("bathroom sink", (0.5, 0.4, 0.8), (0.8, 0.5, 0.9)),
    ("basin", (0.5, 0.4, 0.8), (0.7, 0.5, 0.9)),
    ("wash basin", (0.5, 0.4, 0.8), (0.7, 0.5, 0.9)),
]
_TUBS: list[_Entry] = [
    ("bathtub", (1.5, 0.7, 0.5), (1.7, 0.8, 0.6)),
    ("shower", (0.8, 0.8, 0.15), (0.9, 0.9, 0.2)),
]
_FRIDGES: list[_Entry] = [
    ("refrigerator", (0.6, 0.62, 1.7), (0.8, 0.72, 1.95)),
    ("fridge", (0.6, 0.62, 1.7), (0.8, 0.72, 1.95)),
    ("water cooler", (0.3, 0.3, 1.0), (0.4, 0.4, 1.2)),
]
_STOVES: list[_Entry] = [
    ("stove", (0.6, 0.6, 0.9), (0.76, 0.65, 0.95)),
    ("oven", (0.6, 0.6, 0.85), (0.76, 0.65, 0.92)),
]
_WASHERS: list[_Entry] = [
    ("washing machine", (0.6, 0.58, 0.85), (0.62, 0.62, 0.88)),
    ("clothes dryer", (0.6, 0.58, 0.85), (0.62, 0.62, 0.88)),
    ("dishwasher", (0.6, 0.58, 0.82), (0.62, 0.62, 0.86)),
]
_PIANOS: list[_Entry] = [
    ("piano", (1.3, 0.55, 1.1), (1.5, 0.65, 1.3)),
    ("fireplace", (1.2, 0.4, 1.0), (1.6, 0.5, 1.2)),
]
_FLOOR_SMALL: list[_Entry] = [
    ("trash can", (0.25, 0.25, 0.35), (0.38, 0.38, 0.65)),
    ("trashcan", (0.25, 0.25, 0.35), (0.38, 0.38, 0.65)),
    ("trash bin", (0.25, 0.25, 0.35), (0.38, 0.38, 0.6)),
    ("bin", (0.25, 0.25, 0.3), (0.4, 0.4, 0.5)),
    ("bucket", (0.25, 0.25, 0.25), (0.32, 0.32, 0.35)),
    ("hamper", (0.35, 0.35, 0.5), (0.45, 0.45, 0.65)),
    ("heater", (0.3, 0.2, 0.4), (0.5, 0.3, 0.6)),
    ("fan", (0.3, 0.3, 0.8), (0.4, 0.4, 1.2)),
    ("fire extinguisher", (0.15, 0.15, 0.45), (0.2, 0.2, 0.6)),
    ("urn", (0.3, 0.3, 0.5), (0.45, 0.45, 0.8)),
]
_FLOOR_BOXES: list[_Entry] = [
    ("radiator", (0.6, 0.12, 0.5), (1.2, 0.15, 0.7)),
    ("air conditioner", (0.6, 0.25, 0.5), (0.9, 0.3, 0.7)),
    ("suitcase", (0.4, 0.25, 0.55), (0.5, 0.3, 0.75)),
    ("treadmill", (0.7, 1.6, 0.3), (0.8, 1.8, 0.4)),
    ("exercise equipment", (0.6, 0.8, 0.8), (0.8, 1.2, 1.2)),
    ("gym equipment", (0.6, 0.8, 0.8), (0.8, 1.2, 1.2)),
    ("weight machine", (0.8, 1.0, 1.4), (1.0, 1.4, 1.8)),
    ("ladder", (0.45, 0.15, 1.2), (0.55, 0.2, 1.8)),
    ("easel", (0.5, 0.4, 1.3), (0.7, 0.5, 1.7)),
    ("guitar", (0.35, 0.12, 1.0), (0.4, 0.15, 1.1)),
    ("drums", (0.6, 0.6, 0.6), (0.8, 0.8, 0.8)),
    ("coat rack", (0.4, 0.4, 1.6), (0.5, 0.5, 1.8)),
]
_PLANTS: list[_Entry] = [
    ("plant", (0.35, 0.35, 0.7), (0.6, 0.6, 1.4)),
    ("plants", (0.4, 0.4, 0.6), (0.7, 0.7, 1.2)),
    ("potted plant", (0.35, 0.35, 0.6), (0.5, 0.5, 1.1)),
    ("tree", (0.5, 0.5, 1.5), (0.7, 0.7, 1.9)),
]
_FLOOR_LAMPS: list[_Entry] = [
    ("floor lamp", (0.35, 0.35, 1.4), (0.45, 0.45, 1.75)),
]
_TABLE_LAMPS: list[_Entry] = [
    ("lamp", (0.22, 0.22, 0.35), (0.32, 0.32, 0.55)),
    ("table lamp", (0.22, 0.22, 0.35), (0.32, 0.32, 0.55)),
    ("light", (0.15, 0.15, 0.25), (0.25, 0.25, 0.4)),
]
_SCREENS: list[_Entry] = [
    ("tv", (0.8, 0.22, 0.5), (1.3, 0.28, 0.8)),
    ("monitor", (0.45, 0.2, 0.35), (0.65, 0.22, 0.48)),
    ("computer", (0.45, 0.2, 0.35), (0.6, 0.22, 0.45)),
]
_DEVICES: list[_Entry] = [
    ("laptop", (0.3, 0.22, 0.2), (0.38, 0.26, 0.24)),
    ("tablet", (0.2, 0.15, 0.02), (0.26, 0.19, 0.03)),
]
_APPLIANCES_SMALL: list[_Entry] = [
    ("microwave", (0.45, 0.35, 0.26), (0.55, 0.4, 0.32)),
    ("printer", (0.4, 0.35, 0.2), (0.5, 0.42, 0.28)),
    ("coffee maker", (0.2, 0.25, 0.3), (0.25, 0.3, 0.38)),
    ("speaker", (0.15, 0.15, 0.25), (0.25, 0.22, 0.4)),
    ("projector", (0.25, 0.2, 0.1), (0.32, 0.25, 0.14)),
    ("keyboard", (0.4, 0.13, 0.03), (0.46, 0.16, 0.04)),
    ("telephone", (0.15, 0.18, 0.08), (0.2, 0.22, 0.1)),
    ("phone", (0.07, 0.14, 0.02), (0.08, 0.16, 0.02)),
    ("scale", (0.28, 0.28, 0.03), (0.33, 0.33, 0.05)),
    ("range hood", (0.6, 0.45, 0.3), (0.9, 0.5, 0.4)),
]
_VASES: list[_Entry] = [
    ("vase", (0.12, 0.12, 0.2), (0.2, 0.2, 0.4)),
    ("flowerpot", (0.15, 0.15, 0.15), (0.25, 0.25, 0.25)),
    ("plant pot", (0.15, 0.15, 0.15), (0.25, 0.25, 0.25)),
    ("pot", (0.2, 0.2, 0.15), (0.3, 0.3, 0.25)),
    ("flowers", (0.15, 0.15, 0.3), (0.25, 0.25, 0.45)),
    ("flower", (0.1, 0.1, 0.25), (0.18, 0.18, 0.4)),
    ("teapot", (0.18, 0.15, 0.15), (0.24, 0.2, 0.2)),
    ("candlestick", (0.08, 0.08, 0.2), (0.12, 0.12, 0.35)),
    ("candelabra", (0.2, 0.1, 0.3), (0.3, 0.15, 0.45)),
]
_BOTTLES: list[_Entry] = [
    ("bottle", (0.07, 0.07, 0.22), (0.09, 0.09, 0.32)),
    ("bottles", (0.15, 0.08, 0.22), (0.25, 0.1, 0.3)),
    ("soap dispenser", (0.07, 0.07, 0.15), (0.09, 0.09, 0.2)),
    ("shampoo", (0.06, 0.06, 0.18), (0.08, 0.08, 0.24)),
    ("toiletry", (0.05, 0.05, 0.12), (0.08, 0.08, 0.2)),
    ("fire alarm", (0.1, 0.1, 0.05), (0.14, 0.14, 0.07)),
]
_ROUND_SMALL: list[_Entry] = [
    ("bowl", (0.2, 0.2, 0.07), (0.3, 0.3, 0.1)),
    ("fruit bowl", (0.22, 0.22, 0.1), (0.32, 0.32, 0.14)),
    ("bowl of fruit", (0.22, 0.22, 0.1), (0.32, 0.32, 0.14)),
    ("plate", (0.22, 0.22, 0.02), (0.28, 0.28, 0.03)),
    ("decorative plate", (0.22, 0.22, 0.02), (0.3, 0.3, 0.03)),
    ("cup", (0.07, 0.07, 0.09), (0.09, 0.09, 0.12)),
    ("glass", (0.06, 0.06, 0.1), (0.08, 0.08, 0.15)),
    ("candle", (0.06, 0.06, 0.08), (0.1, 0.1, 0.2)),
    ("candles", (0.12, 0.06, 0.1), (0.2, 0.1, 0.2)),
    ("basket", (0.25, 0.25, 0.15), (0.4, 0.4, 0.25)),
    ("container", (0.15, 0.15, 0.12), (0.3, 0.3, 0.25)),
    ("pan", (0.25, 0.25, 0.05), (0.32, 0.32, 0.08)),
    ("ball", (0.12, 0.12, 0.12), (0.25, 0.25, 0.25)),
    ("toilet paper", (0.11, 0.11, 0.1), (0.12, 0.12, 0.11)),
    ("paper towel", (0.12, 0.12, 0.25), (0.14, 0.14, 0.28)),
    ("hat", (0.25, 0.25, 0.1), (0.32, 0.32, 0.15)),
]
_BLOCKS: list[_Entry] = [
    ("box", (0.2, 0.2, 0.12), (0.4, 0.3, 0.25)),
    ("boxes", (0.35, 0.3, 0.2), (0.5, 0.4, 0.35)),
    ("tissue box", (0.22, 0.12, 0.08), (0.25, 0.13, 0.12)),
    ("tray", (0.35, 0.25, 0.03), (0.5, 0.35, 0.05)),
    ("soap", (0.08, 0.05, 0.03), (0.1, 0.07, 0.04)),
    ("soap dish", (0.12, 0.09, 0.03), (0.14, 0.1, 0.04)),
    ("placemat", (0.4, 0.3, 0.01), (0.45, 0.33, 0.01)),
    ("paper", (0.21, 0.29, 0.01), (0.22, 0.3, 0.02)),
    ("bag", (0.3, 0.15, 0.3), (0.45, 0.2, 0.4)),
    ("purse", (0.25, 0.1, 0.2), (0.35, 0.15, 0.28)),
    ("handbag", (0.25, 0.1, 0.2), (0.35, 0.15, 0.28)),
    ("shoes", (0.25, 0.3, 0.1), (0.3, 0.33, 0.13)),
    ("case", (0.25, 0.15, 0.1), (0.4, 0.25, 0.15)),
    ("control", (0.05, 0.17, 0.02), (0.06, 0.2, 0.03)),
    ("cloth", (0.3, 0.3, 0.02), (0.4, 0.4, 0.04)),
]
_BOOKS: list[_Entry] = [
    ("book", (0.16, 0.22, 0.03), (0.22, 0.3, 0.06)),
    ("books", (0.2, 0.25, 0.1), (0.3, 0.3, 0.2)),
]
_FIGURES: list[_Entry] = [
    ("statue", (0.15, 0.15, 0.3), (0.25, 0.25, 0.5)),
    ("sculpture", (0.15, 0.15, 0.25), (0.3, 0.3, 0.5)),
    ("figure", (0.08, 0.08, 0.15), (0.12, 0.12, 0.25)),
    ("bust", (0.2, 0.18, 0.35), (0.25, 0.22, 0.45)),
    ("knickknack", (0.06, 0.06, 0.08), (0.12, 0.12, 0.15)),
    ("trinket", (0.06, 0.06, 0.06), (0.1, 0.1, 0.12)),
    ("ornament", (0.08, 0.08, 0.1), (0.15, 0.15, 0.2)),
    ("decoration", (0.1, 0.1, 0.12), (0.2, 0.2, 0.3)),
    ("decor", (0.1, 0.1, 0.12), (0.2, 0.2, 0.3)),
    ("decorative object", (0.1, 0.1, 0.12), (0.2, 0.2, 0.3)),
    ("doll", (0.12, 0.08, 0.25), (0.18, 0.12, 0.4)),
    ("toy", (0.1, 0.1, 0.08), (0.25, 0.2, 0.2)),
    ("stuffed animal", (0.2, 0.15, 0.2), (0.3, 0.25, 0.35)),
    ("plush toy", (0.15, 0.12, 0.15), (0.25, 0.2, 0.3)),
    ("mask", (0.15, 0.08, 0.2), (0.2, 0.1, 0.28)),
]
_SOFT: list[_Entry] = [
    ("pillow", (0.5, 0.35, 0.12), (0.65, 0.45, 0.18)),
    ("pillows", (0.8, 0.4, 0.15), (1.1, 0.5, 0.2)),
    ("cushion", (0.35, 0.35, 0.12), (0.45, 0.45, 0.16)),
    ("towel", (0.3, 0.25, 0.06), (0.45, 0.3, 0.1)),
    ("towels", (0.35, 0.3, 0.12), (0.45, 0.35, 0.2)),
    ("blanket", (0.5, 0.4, 0.08), (0.8, 0.5, 0.12)),
    ("clothes", (0.35, 0.3, 0.1), (0.5, 0.4, 0.2)),
]
_HUNG: list[_Entry] = [
    ("picture", (0.4, 0.03, 0.3), (1.0, 0.04, 0.8)),
    ("painting", (0.5, 0.03, 0.4), (1.2, 0.04, 0.9)),
    ("photo", (0.2, 0.02, 0.15), (0.35, 0.03, 0.3)),
    ("picture frame", (0.25, 0.03, 0.2), (0.45, 0.04, 0.35)),
    ("wall frame", (0.3, 0.03, 0.25), (0.6, 0.04, 0.5)),
    ("art", (0.4, 0.03, 0.3), (1.0, 0.04, 0.8)),
    ("wall art", (0.4, 0.03, 0.3), (1.0, 0.04, 0.8)),
    ("wall decoration", (0.2, 0.04, 0.2), (0.5, 0.06, 0.5)),
    ("poster", (0.4, 0.01, 0.55), (0.6, 0.01, 0.9)),
    ("mirror", (0.4, 0.03, 0.6), (0.8, 0.04, 1.0)),
    ("whiteboard", (0.9, 0.03, 0.6), (1.5, 0.04, 0.9)),
    ("bulletin board", (0.6, 0.03, 0.45), (1.0, 0.04, 0.7)),
    ("board", (0.6, 0.03, 0.45), (1.0, 0.04, 0.7)),
    ("sign", (0.25, 0.02, 0.15), (0.4, 0.03, 0.25)),
    ("exit sign", (0.3, 0.05, 0.15), (0.35, 0.06, 0.18)),
    ("panel", (0.3, 0.03, 0.3), (0.6, 0.04, 0.6)),
    ("vent", (0.3, 0.03, 0.15), (0.5, 0.04, 0.25)),
    ("light switch", (0.08, 0.02, 0.12), (0.1, 0.02, 0.14)),
    ("switch", (0.08, 0.02, 0.12), (0.1, 0.02, 0.14)),
    ("thermostat", (0.1, 0.03, 0.1), (0.14, 0.04, 0.14)),
    ("towel bar", (0.5, 0.08, 0.04), (0.7, 0.1, 0.05)),
    ("toilet paper holder", (0.15, 0.1, 0.06), (0.18, 0.12, 0.08)),
    ("paper towel dispenser", (0.3, 0.12, 0.35), (0.35, 0.15, 0.4)),
    ("wall cabinet", (0.6, 0.33, 0.6), (1.0, 0.38, 0.8)),
    ("wall sconce", (0.12, 0.12, 0.2), (0.18, 0.15, 0.3)),
]
_CLOCKS: list[_Entry] = [
    ("clock", (0.25, 0.04, 0.25), (0.4, 0.05, 0.4)),
    ("thermostat", (0.1, 0.03, 0.1), (0.14, 0.04, 0.14)),
]

_B = Callable[..., c.Built]
_FAMILIES: list[tuple[str, _B, tuple, list[_Entry]]] = [
    ("wall", c.cabinet, c.WOOD + c.WHITE + c.DARK, _CABINETS),
    ("wall", c.wardrobe, c.WOOD + c.WHITE, _TALL),
    ("wall", c.shelf, c.WOOD + c.WHITE + c.METAL, _SHELVES),
    ("wall", c.desk, c.WOOD + c.WHITE, _DESKS),
    ("free", c.table, c.WOOD + c.WHITE + c.DARK, _TABLES),
    ("free", c.round_table, c.WOOD + c.WHITE, _SMALL_TABLES),
    ("free", c.chair, c.WOOD + c.DARK + c.FABRIC, _CHAIRS),
    ("free", c.office_chair, c.DARK + c.FABRIC, _SWIVEL),
    ("free", c.armchair, c.FABRIC, _ARMCHAIRS),
    ("wall", c.sofa, c.FABRIC, _SOFAS),
    ("free", c.stool, c.WOOD + c.METAL, _STOOLS),
    ("free", c.ottoman, c.FABRIC, _OTTOMANS),
    ("wall", c.bench, c.WOOD, _BENCHES),
    ("wall", c.bed, c.WOOD, _BEDS),
    ("wall", c.toilet, c.WHITE, _TOILETS),
    ("wall", c.sink, c.WOOD + c.WHITE, _SINKS),
    ("wall", c.bathtub, c.WHITE, _TUBS),
    ("wall", c.refrigerator, c.WHITE + c.METAL, _FRIDGES),
    ("wall", c.stove, c.WHITE + c.METAL, _STOVES),
    ("wall", c.washing_machine, c.WHITE + c.METAL, _WASHERS),
    ("wall", c.piano, c.DARK + c.WOOD, _PIANOS),
    ("wall", c.trash_can, c.METAL + c.DARK + c.WHITE, _FLOOR_SMALL),
    ("wall", c.block, c.METAL + c.DARK + c.WHITE + c.BRIGHT, _FLOOR_BOXES),
    ("wall", c.plant, c.GREEN, _PLANTS),
    ("wall", c.lamp, c.WHITE + c.FABRIC, _FLOOR_LAMPS),
    ("on", c.lamp, c.WHITE + c.FABRIC, _TABLE_LAMPS),
    ("on", c.screen, c.DARK, _SCREENS),
    ("on", c.laptop, c.METAL + c.DARK, _DEVICES),
    ("on", c.microwave, c.WHITE + c.METAL + c.DARK, _APPLIANCES_SMALL),
    ("on", c.vase, c.BRIGHT + c.WHITE, _VASES),
    ("on", c.bottle, c.GREEN + c.BRIGHT, _BOTTLES),
    ("on", c.cylinder, c.BRIGHT + c.WHITE + c.WOOD, _ROUND_SMALL),
    ("on", c.block, c.BRIGHT + c.WHITE + c.WOOD, _BLOCKS),
    ("on", c.book, c.BRIGHT, _BOOKS),
    ("on", c.vase, c.WHITE + c.DARK + c.BRIGHT, _FIGURES),
    ("on", c.block, c.WHITE + c.FABRIC + c.BRIGHT, _SOFT),
    ("hung", c.picture, c.BRIGHT + c.GREEN + c.WHITE, _HUNG),
    ("hung", c.clock, c.WHITE, _CLOCKS),
]

_SURFACES: tuple[str, ...] = tuple(
    name
    for family in (_CABINETS, _SHELVES, _DESKS, _TABLES, _SMALL_TABLES, _WASHERS)
    for name, *_ in family
) + tuple(name for family in (_PIANOS, _BEDS, _SOFAS, _ARMCHAIRS) for name, *_ in family)
"""Classes whose instances have a top other objects may rest on (where the builder gives
one: a tall shelf or a wardrobe has none)."""

_HANG = {"mirror": (1.0, 1.3), "whiteboard": (0.9, 1.1), "clock": (1.6, 1.9)}
_HANG.update({"light switch": (1.0, 1.2), "switch": (1.0, 1.2), "thermostat": (1.3, 1.5)})
_HANG.update({"towel bar": (0.9, 1.2), "toilet paper holder": (0.6, 0.8), "vent": (1.9, 2.2)})
_HANG.update({"wall cabinet": (1.4, 1.6), "exit sign": (2.0, 2.2), "wall sconce": (1.6, 1.9)})


def _catalogue() -> dict[str, ClassSpec]:
    out: dict[str, ClassSpec] = {}
    for placement, build, palette, members in _FAMILIES:
        for name, lo, hi in members:
            if name in out:
                continue
            supports = _SURFACES if placement == "on" else ()
            hang = _HANG.get(name, (1.2, 1.6))
            out[name] = ClassSpec(name, lo, hi, placement, build, palette, supports, hang)  # type: ignore[arg-type]
    return out


MATTERPORT_CATALOGUE: dict[str, ClassSpec] = _catalogue()
"""Every class of the Matterport-like world, by name."""

MATTERPORT_CLASS_NAMES: tuple[str, ...] = ("void", *c.STRUCTURE_CLASSES, *MATTERPORT_CATALOGUE)
"""Class id -> name of Matterport-like scenes (one vocabulary for every such scene)."""


def _names(*families: list[_Entry]) -> tuple[str, ...]:
    return tuple(dict.fromkeys(n for fam in families for n, *_ in fam))


MATTERPORT_ROOM_TYPES: dict[str, RoomType] = {
    r.name: r
    for r in [
        RoomType("living room", (
            ("sofa", 0.6, (1, 1)), ("couch", 0.5, (1, 1)), ("coffee table", 0.9, (1, 1)),
            ("armchair", 0.6, (1, 2)), ("sofa chair", 0.4, (1, 2)), ("tv stand", 0.7, (1, 1)),
            ("bookshelf", 0.4, (1, 1)), ("shelf", 0.4, (1, 1)), ("fireplace", 0.3, (1, 1)),
            ("side table", 0.6, (1, 2)), ("end table", 0.4, (1, 1)), ("ottoman", 0.3, (1, 1)),
            ("piano", 0.1, (1, 1)), ("tv", 0.8, (1, 1)), ("cabinet", 0.4, (1, 1)),
        )),
        RoomType("bedroom", (
            ("bed", 1.0, (1, 1)), ("nightstand", 0.7, (1, 2)), ("bedside table", 0.3, (1, 1)),
            ("wardrobe", 0.5, (1, 1)), ("closet", 0.3, (1, 1)), ("dresser", 0.5, (1, 1)),
            ("chest of drawers", 0.3, (1, 1)), ("desk", 0.3, (1, 1)), ("chair", 0.3, (1, 1)),
            ("bench", 0.2, (1, 1)), ("tv", 0.2, (1, 1)),
        )),
        RoomType("kitchen", (
            ("kitchen cabinet", 1.0, (2, 4)), ("refrigerator", 0.7, (1, 1)),
            ("fridge", 0.3, (1, 1)), ("stove", 0.7, (1, 1)), ("oven", 0.4, (1, 1)),
            ("dishwasher", 0.5, (1, 1)), ("kitchen counter", 0.5, (1, 2)),
            ("kitchen island", 0.3, (1, 1)), ("dining table", 0.3, (1, 1)),
            ("stool", 0.5, (1, 3)), ("microwave", 0.8, (1, 1)), ("coffee maker", 0.4, (1, 1)),
        )),
        RoomType("bathroom", (
            ("toilet", 1.0, (1, 1)), ("sink", 0.7, (1, 1)), ("washbasin", 0.3, (1, 1)),
            ("bathtub", 0.6, (1, 1)), ("shower", 0.3, (1, 1)), ("bath cabinet", 0.5, (1, 1)),
            ("bathroom cabinet", 0.3, (1, 1)), ("vanity", 0.3, (1, 1)),
            ("washing machine", 0.3, (1, 1)), ("clothes dryer", 0.2, (1, 1)),
            ("bidet", 0.1, (1, 1)),
        )),
        RoomType("office", (
            ("desk", 1.0, (1, 2)), ("computer desk", 0.3, (1, 1)), ("bookshelf", 0.6, (1, 2)),
            ("bookcase", 0.3, (1, 1)), ("cabinet", 0.5, (1, 1)), ("shelving", 0.4, (1, 1)),
            ("office table", 0.3, (1, 1)), ("drawers", 0.3, (1, 1)), ("armchair", 0.2, (1, 1)),
            ("monitor", 1.0, (1, 2)), ("computer", 0.3, (1, 1)), ("printer", 0.5, (1, 1)),
        )),
        RoomType("dining room", (
            ("dining table", 1.0, (1, 1)), ("cabinet", 0.5, (1, 2)), ("cupboard", 0.3, (1, 1)),
            ("shelf", 0.4, (1, 1)), ("display case", 0.3, (1, 1)), ("round table", 0.2, (1, 1)),
            ("chest", 0.2, (1, 1)),
        )),
    ]
}  # fmt: skip
"""Large furniture per room kind; order is placement order (big pieces first)."""

_DECOR = _names(_VASES, _FIGURES, _ROUND_SMALL[:5], _BOOKS, _TABLE_LAMPS)
_WALL_DECOR = _names(_HUNG[:10], _CLOCKS[:1])
_FLOOR = _names(_FLOOR_SMALL, _PLANTS, _FLOOR_LAMPS)
MATTERPORT_FILL: dict[str, tuple[str, ...]] = {
    "living room": (*_DECOR, *_WALL_DECOR, *_FLOOR, "pillow", "cushion", "blanket", "remote"),
    "bedroom": (*_DECOR, *_WALL_DECOR, *_FLOOR, *_names(_SOFT), "clothes", "bag", "shoes"),
    "kitchen": (*_names(_ROUND_SMALL, _BOTTLES[:2], _VASES[:4]), "tray", "box", "toaster",
                "bowl", "plate", "cup", "glass", "teapot", "pan", "pot", "clock", "trash can",
                "trashcan", "plant", "vent", "towel", "paper towel", "fire extinguisher"),
    "bathroom": (*_names(_BOTTLES, _SOFT[3:5]), "mirror", "towel bar", "toilet paper",
                 "toilet paper holder", "soap", "soap dish", "tissue box", "trash can", "bin",
                 "basket", "hamper", "scale", "plant", "picture", "vent", "light switch"),
    "office": (*_names(_DEVICES, _APPLIANCES_SMALL[4:7], _BOOKS, _BLOCKS[:4]),
               *_WALL_DECOR, "whiteboard", "bulletin board", "board", "lamp", "table lamp",
               "trash can", "bin", "plant", "potted plant", "fan", "heater", "cup"),
    "dining room": (*_DECOR, *_WALL_DECOR, *_names(_ROUND_SMALL), "plant", "potted plant",
                    "placemat", "tray", "candle", "teapot"),
}  # fmt: skip
"""Per room kind, the small, hung and floor classes a room is filled with (siblings of one
class are common: each draw picks a class, and a drawn class is drawn again more often)."""
MATTERPORT_FILL = {
    k: tuple(n for n in dict.fromkeys(v) if n in MATTERPORT_CATALOGUE)
    for k, v in MATTERPORT_FILL.items()
}

MATTERPORT_COMPANIONS: dict[str, tuple[str, tuple[int, int], tuple[int, ...]]] = {
    "dining table": ("dining chair", (2, 6), (0, 1, 2, 3)),
    "table": ("chair", (1, 4), (0, 1, 2, 3)),
    "round table": ("chair", (2, 3), (0, 1, 2, 3)),
    "kitchen island": ("stool", (1, 3), (0,)),
    "office table": ("chair", (1, 3), (0, 1)),
    "desk": ("office chair", (1, 1), (0,)),
    "computer desk": ("desk chair", (1, 1), (0,)),
}
"""Parent class -> (companion class, count range, sides), as :data:`care_maps.world.catalogue.COMPANIONS`."""
