#!/usr/bin/env python3
"""Open Rerun recordings in the real viewer, headless, and check every view of each.

For each ``.rrd``: spawn the viewer shipped in rerun-sdk (software Vulkan via Mesa's lavapipe
where there is no GPU: ``apt-get install mesa-vulkan-drivers``), open the file, show each view
in turn (activating its tab), read the errors the viewer reports in that view's corner, and
save a screenshot of the view and one of the whole window. Exit status: 0 when every view of
every recording rendered without an error, 1 when some view reported one (or a recording
showed no view), 3 when the viewer cannot start at all (the test suite skips on that only).

    python3 scripts/check_viewer.py out/scene_000.*.rrd --shots shots/ \\
        --time query=1 --readme docs/viewer --width 960

``--time TIMELINE=N`` moves the time cursor of recordings that have that timeline (e.g. to a
query worth showing); ``--readme DIR`` also writes each window screenshot downscaled to
``--width`` pixels and palette-optimised, for the documents.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import socket
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

EXIT_ERRORS, EXIT_NO_VIEWER = 1, 3


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _environment() -> None:
    os.environ.setdefault("WGPU_BACKEND", "vulkan")  # GL lacks R32Float under llvmpipe
    if not os.environ.get("XDG_RUNTIME_DIR"):
        os.environ["XDG_RUNTIME_DIR"] = tempfile.mkdtemp(prefix="rerun-xdg-")


def spawn_viewer(timeout: float = 60.0) -> Any:
    """A headless viewer client, or a RuntimeError saying why none could start."""
    _environment()
    import rerun.experimental as rx

    deadline = time.monotonic() + timeout
    last: Exception | None = None
    while time.monotonic() < deadline:
        try:
            viewer = rx.ViewerClient.spawn(
                headless=True, port=_free_port(), hide_welcome_screen=True
            )
            viewer.get_state()  # answers only once the viewer runs (has a renderer)
            return viewer
        except Exception as err:  # any failure to start means "no viewer"
            last = err
            time.sleep(1.0)
    msg = f"the Rerun viewer cannot start headless: {last}"
    raise RuntimeError(msg)


def _slug(text: str) -> str:
    return re.sub(r"[^a-z0-9]+", "_", text.lower()).strip("_")[:48] or "view"


def _activate(viewer: Any, view_id: str) -> None:
    """Make every Tabs container on the way to the view show it."""
    bp = viewer.get_blueprint()
    tree = bp.blueprint
    key = f"/view/{view_id}"
    changed = False
    while True:
        parent = next(
            (
                path
                for path, parts in tree.items()
                if key in (parts.get("ContainerBlueprint", {}).get("contents") or [])
            ),
            None,
        )
        if parent is None:
            break
        container = tree[parent]["ContainerBlueprint"]
        if container.get("container_kind") == "Tabs" and container.get("active_tab") != key:
            container["active_tab"] = key
            changed = True
        key = parent
    if changed:
        viewer.set_blueprint(tree, of="recording")


def _wait_loaded(viewer: Any, timeout: float) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        state = viewer.get_state()
        if state.views and not state.loading:
            return
        time.sleep(1.0)
    msg = f"the recording did not finish loading within {timeout:.0f} s"
    raise TimeoutError(msg)


def _downscale(src: Path, dst: Path, width: int) -> None:
    from PIL import Image

    image = Image.open(src).convert("RGB")
    height = round(image.height * width / image.width)
    small = image.resize((width, height), Image.Resampling.LANCZOS)
    small = small.quantize(colors=256, method=Image.Quantize.MEDIANCUT, dither=0)
    dst.parent.mkdir(parents=True, exist_ok=True)
    small.save(dst, optimize=True)


def check_recording(
    viewer: Any,
    rrd: Path,
    shots: Path,
    *,
    times: dict[str, int],
    load_timeout: float,
    settle: float,
) -> dict[str, list[str]]:
    """Errors reported per view name of ``rrd``; screenshots under ``shots/<file stem>/``."""
    viewer.open(str(rrd.resolve()))
    _wait_loaded(viewer, load_timeout)
    for timeline, value in times.items():
        try:
            viewer.set_time(timeline, sequence=value, play_state="paused")
        except Exception:  # the recording has no such timeline
            continue
    time.sleep(settle)
    original = viewer.get_blueprint().blueprint
    stem = rrd.name.removesuffix(".rrd")
    out = shots / stem
    out.mkdir(parents=True, exist_ok=True)
    views = viewer.get_state().views
    errors: dict[str, list[str]] = {}
    for i, view in enumerate(views):
        _activate(viewer, view.view_id)
        time.sleep(settle)
        state = {v.view_id: v for v in viewer.get_state().views}
        current = state.get(view.view_id, view)
        errors[view.name or view.view_id] = [
            r.summary for r in current.reports or [] if r.severity == "error"
        ]
        viewer.save_screenshot(str(out / f"{i:02d}_{_slug(view.name or '')}.png"), view.view_id)
    if not views:
        errors["(no view)"] = ["the viewer showed no view of this recording"]
    viewer.set_blueprint(original, of="recording")  # back to the layout as it opens
    time.sleep(settle)
    return errors


def window_shot(viewer: Any, rrd: Path, path: Path, view_name: str | None, settle: float) -> None:
    """A screenshot of the whole window, with the tab of ``view_name`` shown if given."""
    if view_name:
        for view in viewer.get_state().views:
            if view.name == view_name:
                _activate(viewer, view.view_id)
        time.sleep(settle)
    viewer.save_screenshot(str(path))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("rrds", nargs="*", type=Path, help="Recordings to check.")
    parser.add_argument("--shots", type=Path, default=Path("viewer-shots"))
    parser.add_argument("--time", action="append", default=[], metavar="TIMELINE=N")
    parser.add_argument("--readme", type=Path, help="Also write small window screenshots here.")
    parser.add_argument("--width", type=int, default=960, help="Width of --readme screenshots.")
    parser.add_argument(
        "--tab", action="append", default=[], metavar="FILE_STEM=VIEW NAME PREFIX",
        help="Extra window screenshot of a recording with this tab shown (for --readme).",
    )  # fmt: skip
    parser.add_argument("--load-timeout", type=float, default=180.0)
    parser.add_argument("--settle", type=float, default=2.0, help="Seconds to let a view draw.")
    parser.add_argument("--json", type=Path, help="Write {file: {view: [errors]}} here.")
    parser.add_argument("--probe", action="store_true", help="Only check the viewer starts.")
    args = parser.parse_args(argv)
    times = {}
    for item in args.time:
        name, _, value = item.partition("=")
        times[name] = int(value)
    try:
        viewer = spawn_viewer()
    except RuntimeError as err:
        print(err, file=sys.stderr)
        return EXIT_NO_VIEWER
    if args.probe:
        viewer.quit()
        print("the viewer starts")
        return 0
    viewer.quit()
    report: dict[str, dict[str, list[str]]] = {}
    extra_tabs: dict[str, list[str]] = {}
    for item in args.tab:
        stem, _, prefix = item.partition("=")
        extra_tabs.setdefault(stem, []).append(prefix)
    for rrd in args.rrds:
        viewer = spawn_viewer()  # a fresh viewer per file: nothing carries over
        try:
            errors = check_recording(
                viewer, rrd, args.shots, times=times, load_timeout=args.load_timeout,
                settle=args.settle,
            )  # fmt: skip
            report[str(rrd)] = errors
            stem = rrd.name.removesuffix(".rrd")
            views = viewer.get_state().views
            shots = [(args.shots / f"{stem}.png", None)]
            for prefix in extra_tabs.get(stem, []):
                name = next((v.name for v in views if v.name.startswith(prefix)), None)
                if name:
                    shots.append((args.shots / f"{stem}.{_slug(prefix)}.png", name))
            # the first screenshot shows the blueprint as it opens: each Tabs on its first tab
            window_shot(viewer, rrd, shots[0][0], None, args.settle)
            for path, name in shots[1:]:
                window_shot(viewer, rrd, path, name, args.settle)
            if args.readme:
                for path, _ in shots:
                    _downscale(path, args.readme / path.name, args.width)
        finally:
            viewer.quit()
        bad = {view: errs for view, errs in errors.items() if errs}
        print(f"{rrd}: {len(errors)} views, {sum(map(len, bad.values()))} errors")
        for view, errs in bad.items():
            print(f"  {view}: {'; '.join(errs)}")
    if args.json:
        args.json.write_text(json.dumps(report, indent=1))
    failed = any(errs for errors in report.values() for errs in errors.values())
    return EXIT_ERRORS if failed else 0


if __name__ == "__main__":
    sys.exit(main())
