"""The desktop app's panel, drawn with Dear ImGui over an `AppState` after the model each frame: `draw_panel` (the
live numbers, time, the tabs, the file line) and one function per tab (View, Path, Edit, Inspect). Buttons call the
state's actions through `AppState._attempt`, so that an error is one line on the status line.
"""

from __future__ import annotations

import math
from pathlib import Path

from imgui_bundle import imgui

from splatreel.constants import NEAR_PLANE

from .app_data import PATH_FORMATS, Inspector, MeasureTape, wrap_text
from .camera_path import CameraPath
from .overlay import SELECTION_COLOR
from .pick import peak_time, vector_text
from .render_settings import COMPOSITE_ORDERS, RENDER_MODES, VALUE_MODES, RenderSettings
from .selection import normalise_rect
from .state import AppState


def draw_panel(app: AppState) -> None:
    """The app's one window of controls."""
    imgui.set_next_window_pos((10, 10), imgui.Cond_.first_use_ever)
    imgui.set_next_window_size((370, 0), imgui.Cond_.first_use_ever)
    imgui.begin("splatreel")
    st, pb = app._stats, app.playback
    imgui.text(f"{imgui.get_io().framerate:5.1f} FPS  frame {st.frame_ms:5.1f} ms")
    imgui.text(f"sort {st.sort_ms:5.1f} ms  draw {st.frame.draw_ms + st.frame.upload_ms:5.1f} ms")
    imgui.text(f"visible {st.frame.visible:,} / {st.frame.total:,} Gaussians")
    why = "moving" if st.moving else "animating" if st.playing else None
    imgui.text(f"resolution {100 * st.scale:3.0f}%" + (f"  ({why})" if why and st.scale < 1 else ""))

    imgui.separator_text("Time")
    t0, t1 = pb.time_range
    if imgui.arrow_button("##back", imgui.Dir.left):
        pb.step(-1)
    imgui.same_line()
    if imgui.button("Pause" if pb.playing else "Play"):
        pb.playing = not pb.playing
    imgui.same_line()
    if imgui.arrow_button("##on", imgui.Dir.right):
        pb.step(1)
    if imgui.is_item_hovered():
        imgui.set_tooltip("one frame on (right arrow; left arrow: back)")
    imgui.same_line()
    _, pb.loop = imgui.checkbox("loop", pb.loop)
    changed, value = imgui.slider_float("time", pb.time, t0, t1, "%.3f")
    if changed:
        pb.time, pb.playing = value, False
    _, pb.speed = imgui.slider_float("speed", pb.speed, 0.0, 4.0, "%.2fx")

    # the rest in tabs: as sections they outgrew a 720-pixel window
    if imgui.begin_tab_bar("##sections"):
        for name, draw, selected in (("View", view_tab, False),
                                     ("Path", path_tab, False),
                                     ("Edit", edit_tab, app._edit_tab_first),
                                     ("Inspect", inspect_tab, app._inspect.reveal)):
            flags = imgui.TabItemFlags_.set_selected if selected else 0
            if imgui.begin_tab_item(name, None, flags)[0]:
                draw(app)
                imgui.end_tab_item()
        app._edit_tab_first = app._inspect.reveal = False
        imgui.end_tab_bar()
    app._apply_crop_edits()
    ed = app._editor
    if ed.drag is not None:  # the selection rectangle (window coordinates, as imgui draws)
        x0, y0, x1, y1 = normalise_rect(*ed.drag)
        r, g, b = SELECTION_COLOR
        imgui.get_foreground_draw_list().add_rect((x0, y0), (x1, y1),
                                                  imgui.IM_COL32(int(255 * r), int(255 * g), int(255 * b), 255),
                                                  0.0, 1.5)

    imgui.separator_text("File")
    changed, app._open_text = imgui.input_text("##open", app._open_text)
    imgui.same_line()
    if imgui.button("Open"):
        app._pending_open = app._open_text
    status = app.status or "drop a model file on the window to open it"
    for line in wrap_text(status, imgui.get_content_region_avail().x, lambda s: imgui.calc_text_size(s).x):
        imgui.text(line)
    imgui.end()


def view_tab(app: AppState) -> None:
    """The View tab: the camera, the dataset cameras, the look (`RenderSettings`) and the resolution."""
    st, s, c = app._stats, app.settings, app.controller
    imgui.separator_text("Camera")
    if imgui.button("Reset (R)"):
        c.reset(app.framing)
    imgui.same_line()
    _, app._fly = imgui.checkbox("fly mode (F)", app._fly)
    _, c.fov = imgui.slider_float("fov", c.fov, 10.0, 120.0, "%.0f deg")
    if app._views:
        _, app._view_index = imgui.slider_int("dataset view", app._view_index, 0, len(app._views) - 1)
        if imgui.button("Snap to dataset camera"):
            app.snap_to_view()
        imgui.same_line()
        imgui.text(Path(app._views[app._view_index].name).name)
        _, app._show_cameras = imgui.checkbox("show dataset cameras", app._show_cameras)

    imgui.separator_text("Look")
    _, mode = imgui.combo("mode", RENDER_MODES.index(s.mode), list(RENDER_MODES))
    s.mode = RENDER_MODES[mode]
    if s.mode in VALUE_MODES:  # the colour map's legend
        lo, hi = st.frame.value_range
        imgui.text_wrapped({
            "depth": f"red = near ({lo:.3g}), blue = far ({hi:.3g})",
            "speed": f"blue = still ({lo:.3g}), red = fast ({hi:.3g} units per unit of model time)",
            "lifespan": f"time each Gaussian is drawn: blue = brief, red = the whole time range ({hi:.3g})",
            "fade": "temporal opacity factor: red = at its peak (1), blue = fading in or out",
        }[s.mode])
    changed, scale = imgui.slider_float("splat scale", s.splat_scale, 0.05, 3.0, "%.2f",
                                        imgui.SliderFlags_.always_clamp)
    if changed:  # only then: the slider's float32 round trip would change a value given on the command line
        s.splat_scale = scale
    footprint_controls(s)
    max_deg = app.renderer.splats.sh_degree if app.renderer.splats is not None else 0
    deg = max_deg if s.sh_degree is None else min(s.sh_degree, max_deg)
    changed, deg = imgui.slider_int("SH degree", deg, 0, max_deg)
    if changed:
        s.sh_degree = deg
    _, bg = imgui.color_edit3("background", list(s.background))
    s.background = tuple(float(x) for x in bg)
    _, comp = imgui.combo("blending", COMPOSITE_ORDERS.index(s.composite), list(COMPOSITE_ORDERS))
    s.composite = COMPOSITE_ORDERS[comp]
    res = app.resolution
    changed, eighths = imgui.slider_int("resolution", round(8 * res.step_of(res.scale)), 2, 8, "%d/8")
    if changed:
        res.scale = eighths / 8
    _, res.adaptive = imgui.checkbox("lower while moving", res.adaptive)
    if imgui.is_item_hovered():
        imgui.set_tooltip(f"draw fewer pixels while the view moves, to keep frames under {res.budget_ms:.0f} ms")
    if res.adaptive:
        imgui.same_line()
        changed, lower = imgui.checkbox("and playing", not res.sharp_playback)
        if changed:
            res.sharp_playback = not lower
        if imgui.is_item_hovered():
            imgui.set_tooltip("also while the animation plays under a still camera (sharp again when paused)")
    if imgui.button("Screenshot (P)"):
        app._screenshot_request = app._next_screenshot_name()


def footprint_controls(s: RenderSettings) -> None:
    """The footprint caps (`sorting.Footprint`; checkbox and slider each, off by default), near plane and
    temporal fade."""
    s.max_std_dev = _optional_slider(
        s.max_std_dev, "limit reach", "std-devs##reach", 1.0, 3.3, math.sqrt(8.0),
        "draw each splat out to at most this many std-devs: fewer pixels, harder edges\n"
        "(off: out to alpha 1/255 as the trainer, ~3.3; web viewers 2.83; fast 2.24)")
    s.max_screen_radius = _optional_slider(
        s.max_screen_radius, "limit screen size", "of height##radius", 0.01, 1.0, 0.25,
        "cap each splat's radius at a share of the window height,\n"
        "against huge splats close to the camera filling the screen")
    changed, near = imgui.slider_float("near plane", s.near_plane, 0.001, 1.0, "%.3f",
                                       imgui.SliderFlags_.logarithmic | imgui.SliderFlags_.always_clamp)
    if changed:
        s.near_plane = near
    if imgui.is_item_hovered():
        imgui.set_tooltip(f"Gaussians closer than this are not drawn ({NEAR_PLANE:g} as the trainer);\n"
                          "lower it to fly close to or into a model (with limit screen size)")
    changed, smooth = imgui.checkbox("smooth temporal fade", s.temporal_fade == "smooth")
    if changed:
        s.temporal_fade = "smooth" if smooth else "cut"
    if imgui.is_item_hovered():
        imgui.set_tooltip("fade Gaussians out at the end of their time window instead of dropping them\n"
                          "at 0.05 of their opacity (the trainer's cut, a small pop as time plays)")


def path_tab(app: AppState) -> None:
    """The Path tab: make, play, save and load a camera path (`PathEditor`)."""
    pe = app._path
    n = len(pe.path.keys) if pe.path else 0
    imgui.text(f"{n} keyframe(s)" + (f", {pe.path.duration:.1f} s" if n else ""))
    _, pe.key_interval = imgui.slider_float("key spacing", pe.key_interval, 0.1, 5.0, "%.1f s")
    if imgui.button("Add key"):
        app.add_path_key()
    imgui.same_line()
    if imgui.button("Clear"):
        pe.path, pe.playing = None, False
    imgui.same_line()
    if imgui.button("Stop" if pe.playing else "Play path"):
        app._attempt(app._toggle_path)
    _, pe.file = imgui.input_text("path file", pe.file)
    if imgui.button("Save"):
        app._attempt(app._save_path, f"saved camera path {pe.file} ({PATH_FORMATS[pe.nerfstudio]})")
    imgui.same_line()
    if imgui.button("Load"):
        app._attempt(lambda: setattr(pe, "path", CameraPath.load(pe.file, app.model.time_range)),
                      f"loaded camera path {pe.file}")
    imgui.same_line()
    _, pe.overwrite = imgui.checkbox("overwrite", pe.overwrite)
    _, pe.show = imgui.checkbox("show path", pe.show)
    _, fmt = imgui.combo("save as", int(pe.nerfstudio), list(PATH_FORMATS))
    pe.nerfstudio = bool(fmt)
    if imgui.is_item_hovered():
        imgui.set_tooltip("nerfstudio: the path sampled at 30 FPS with each frame's scene time, for ns-render "
                          "camera-path (e.g. a dynamic NeRF of the same data); splatreel reads both")


def edit_tab(app: AppState) -> None:
    """The Edit tab: the crop box, the selection and deletions, and Save edited."""
    ce, ed = app._crop, app._editor
    edits = ed.edits
    imgui.separator_text("Crop box")
    changed, ce.enabled = imgui.checkbox("crop to box", ce.enabled)
    ce.show = ce.show or (changed and ce.enabled)  # turning cropping on shows its box
    imgui.same_line()
    _, ce.show = imgui.checkbox("show box", ce.show)
    step = max(app.framing.radius, 1e-3) / 200.0
    _, ce.lo = imgui.drag_float3("min", ce.lo, step, 0.0, 0.0, "%.3f")
    ce.dragging = imgui.is_item_active()
    _, ce.hi = imgui.drag_float3("max", ce.hi, step, 0.0, 0.0, "%.3f")
    ce.dragging = ce.dragging or imgui.is_item_active()
    if imgui.button("Fit to model"):
        ce.lo, ce.hi = app._extent[0].tolist(), app._extent[1].tolist()
    imgui.same_line()
    edited = ce.edited()
    option = "--crop " + " ".join(f"{x:.6g}" for x in (*edited.lo, *edited.hi))
    if imgui.button("Copy option"):
        imgui.set_clipboard_text(option)
    if imgui.is_item_hovered():
        imgui.set_tooltip(f"{option}\n(for splatreel convert / render / view)")

    imgui.separator_text("Delete Gaussians")
    imgui.text_wrapped("Shift+drag: select what shows in a rectangle now (Shift+Alt+drag: unselect); "
                       "Ctrl+click, then Select or Delete in the Inspect tab")
    imgui.text(f"{edits.num_selected:,} selected, {edits.num_deleted:,} deleted")
    if imgui.button("Delete (Del)"):
        app._attempt(app.delete_selected)
    imgui.same_line()
    if imgui.button("Invert"):  # among the Gaussians in the box (`invert_selection` leaves deleted ones out)
        edits.invert_selection(among=app._in_box(app._crop.shown))
    if imgui.is_item_hovered():
        imgui.set_tooltip("select every Gaussian not selected (e.g. select the object, invert, delete)")
    imgui.same_line()
    if imgui.button("Unselect"):
        edits.clear_selection()
    if imgui.button("Undo (Ctrl+Z)"):
        app._attempt(app._undo)
    imgui.same_line()
    if imgui.button("Restore all"):
        app._attempt(app._restore_all)

    imgui.separator_text("Save")
    imgui.text(f"{len(app.renderer.model):,} of {len(app.model):,} Gaussians shown")
    _, ed.file = imgui.input_text("file##edit", ed.file)
    if imgui.button("Save edited"):
        app._attempt(app._save_edited)
    if imgui.is_item_hovered():
        imgui.set_tooltip("write what the window shows: the cropped model without its deleted Gaussians")
    imgui.same_line()
    _, ed.overwrite = imgui.checkbox("overwrite##edit", ed.overwrite)


def inspect_tab(app: AppState) -> None:
    """The Inspect tab: the Ctrl+clicked pixel's Gaussians (`pick_section`) and the measuring tape."""
    pick_section(app)
    imgui.separator_text("Measure")
    m = app._measure
    if not m.points:
        imgui.text_wrapped("Alt+click two points of the model: the distance between the surfaces there")
        return
    for i, p in enumerate(m.points):
        imgui.text(f"point {i + 1}: {vector_text(p)}")
    imgui.text(f"distance {m.distance:.4g}" if m.distance is not None else "Alt+click the second point")
    if imgui.button("Clear##measure"):
        app._measure = MeasureTape()


def pick_section(app: AppState) -> None:
    """The inspected pixel: its Gaussians by share, the chosen one's attributes, and what to do with it."""
    ins = app._inspect
    if ins.stack is None:
        imgui.text_wrapped("Ctrl+click the model: the Gaussians that make that pixel, largest share first")
        return
    x, y = ins.stack.pixel
    ranked = ins.ranked
    imgui.text(f"pixel ({x}, {y}): alpha {ins.stack.alpha:.3f}, {len(ranked)} Gaussian(s)")
    if not ranked:
        return
    if len(ranked) > 1:
        changed, rank = imgui.slider_int("by share", ins.rank + 1, 1, len(ranked), f"%d of {len(ranked)}")
        if changed:
            ins.rank = rank - 1
    hit = ins.hit
    imgui.text(f"share of the pixel {hit.weight:.3f}  alpha there {hit.alpha:.3f}")
    imgui.color_button("##colour", (*[min(max(c, 0.0), 1.0) for c in hit.color], 1.0))
    imgui.same_line()
    imgui.text("colour (" + ", ".join(f"{c:.3f}" for c in hit.color) + f")  depth {hit.depth:.4g}")
    inspected = app._inspected(app.playback.time)
    if inspected is not None and imgui.begin_table("##gaussian", 2):
        imgui.table_setup_column("attribute", imgui.TableColumnFlags_.width_fixed)
        imgui.table_setup_column("value", imgui.TableColumnFlags_.width_stretch)
        for label, value in inspected[0]:
            imgui.table_next_row()
            imgui.table_next_column()
            imgui.text(label)
            imgui.table_next_column()
            imgui.text(value)
        imgui.end_table()
    if imgui.button("Go to peak time"):
        app.playback.time, app.playback.playing = peak_time(app.renderer.model, hit.index), False
    if imgui.is_item_hovered():
        imgui.set_tooltip("pause at the time this Gaussian shows most")
    imgui.same_line()
    if imgui.button("Select"):
        app._attempt(app.select_inspected)
    if imgui.is_item_hovered():
        imgui.set_tooltip("add this Gaussian to the selection (Edit tab)")
    imgui.same_line()
    if imgui.button("Delete"):
        app._attempt(app._delete_inspected)
    if imgui.is_item_hovered():
        imgui.set_tooltip("delete this Gaussian and inspect the pixel again (Ctrl+Z undoes)")
    imgui.same_line()
    if imgui.button("Clear##inspect"):
        app._inspect = Inspector()


def _optional_slider(value: float | None, label: str, slider: str, lo: float, hi: float, default: float,
                     tooltip: str) -> float | None:
    """A checkbox `label` (None when unticked; ticking starts at `default`) with a slider from `lo` to `hi` beside
    it while ticked; returns the new value."""
    changed, on = imgui.checkbox(label, value is not None)
    if changed:
        value = default if on else None
    if imgui.is_item_hovered():
        imgui.set_tooltip(tooltip)
    if value is not None:
        imgui.same_line()
        # (clamped: a value typed with Ctrl+click stays in range, so the settings stay valid)
        changed, moved = imgui.slider_float(slider, value, lo, hi, "%.2f", imgui.SliderFlags_.always_clamp)
        if changed:  # only then: the slider's float32 round trip would change a value given on the command line
            value = moved
    return value
