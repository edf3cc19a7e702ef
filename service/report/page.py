"""The report's ``index.html``: plain, self-contained HTML (no scripts, no network) around the figures."""

from __future__ import annotations

import html
import math
from typing import TypeGuard

from wandcal.calib.judge.limit_words import limit_lines
from wandcal.calib.judge.placement import NO_REFERENCE, NO_SCALE
from wandcal.calib.judge.verdict import at_limit_text
from wandcal.calib.rig import LISTED_CAMERAS, camera_list, names_camera
from wandcal.service.report.analysis import COVERAGE_GOAL, CameraSummary, ReportData
from wandcal.service.report.figure_style import AXIS_POINTS, FRAME_DOTS, OUTLIER_CROSSES, POINT_DOTS, WAND_DOTS

DASH = "\u2014"  # what a field an older result lacks shows
FAULT_WORDS = {"intrinsics": "intrinsics", "timing": "timing", "wand_scale": "wand scale", "outliers": "outliers",
               "unconverged": "not converged", "undetermined": "undetermined"}  # verdict.faults[].kind, for people
STYLE = """
body { font: 15px/1.45 system-ui, sans-serif; color: #1d2630; margin: 1.5em auto; max-width: 1540px; padding: 0 1em; }
h1 { margin-bottom: 0.2em; } h2 { border-bottom: 1px solid #d5dae0; padding-bottom: 0.2em; margin-top: 1.6em; }
.meta { color: #4a5561; margin: 0.2em 0; }
img { max-width: 100%; height: auto; border: 1px solid #e3e6ea; }
table { border-collapse: collapse; margin: 0.6em 0; }
th, td { border: 1px solid #d5dae0; padding: 0.25em 0.6em; text-align: left; vertical-align: top; }
td ul { margin: 0.2em 0; padding-left: 1.2em; }
th { background: #f2f4f6; font-weight: 600; }
td.num { text-align: right; font-variant-numeric: tabular-nums; }
.advice li { margin: 0.25em 0; } .warnings li { color: #8a4b00; }
.verdict-excellent { color: #1e7d32; font-weight: 600; } .verdict-good { color: #2c6fbb; font-weight: 600; }
.verdict-poor { color: #b3261e; font-weight: 600; }
tr.out-of-time td { color: #8a4b00; font-weight: 600; }
.note { background: #fff8e1; border-left: 4px solid #f0b400; padding: 0.4em 0.8em; }
section.camera { margin-top: 2em; }
"""


def render_page(data: ReportData, figures: dict[str, str]) -> str:
    """The report page.

    Args:
        data: what :func:`wandcal.service.report.analysis.analyse` found.
        figures: file names of the PNGs beside the page: ``"rig"``, ``"wand"`` and each camera's id.
    """
    doc = data.result.doc
    parts = [
        "<!doctype html>",
        '<html lang="en"><head><meta charset="utf-8">',
        '<meta name="viewport" content="width=device-width, initial-scale=1">',
        f"<title>wandcal report: {len(data.cameras)} cameras</title><style>{STYLE}</style></head><body>",
        "<h1>Calibration report</h1>",
        *_summary(data),
        *_advice(data),
        *_list("warnings", "Warnings of the calibration", doc.get("warnings") or [],
               "The calibration raised no warnings."),
    ]
    parts += [f'<p class="note">{_e(n)}</p>' for n in data.notes]
    parts += ['<section id="rig"><h2>The rig</h2>', _img(figures.get("rig"), _rig_alt(data)),
              f'<p class="caption">{_e(rig_caption(data))}</p></section>']
    parts += ['<section id="cameras"><h2>Cameras</h2>', _overview(data), "</section>"]
    parts += _offsets(doc.get("sync"))
    if "wand" in figures:
        parts += ['<section id="wand"><h2>The wand</h2>', _img(figures["wand"], _wand_alt(data)),
                  f'<p class="caption">{_e(wand_caption(data))}</p></section>']
    for cam in data.cameras:
        parts += _camera_section(data, cam, figures.get(cam.id))
    parts.append("</body></html>")
    return "\n".join(parts) + "\n"


def _summary(data: ReportData) -> list[str]:
    doc = data.result.doc
    solver, world, wand = doc.get("solver") or {}, doc.get("world") or {}, doc.get("wand")
    lines = [f"result: {data.result.path.name}"]
    if solver:
        lines.append(f"method {solver.get('method', '?')}: {solver.get('iterations', '?')} iterations, "
                     f"{solver.get('status', '?')}")
    if world:
        scale = " (scale arbitrary: no wand)" if world.get("scale") == "arbitrary" else ""
        lines.append(f"world frame: {world.get('frame', '?')}{scale}" +
                     (f" \u2014 {world['description']}" if world.get("description") else ""))
    if isinstance(wand, dict) and wand.get("length_mean_m"):
        mean, std = wand["length_mean_m"], wand.get("length_std_m") or 0.0
        lines.append(f"wand {1000 * mean:.2f} \u00b1 {1000 * std:.2f} mm ({100 * std / mean:.3f}%) over "
                     f"{wand.get('frames_used', '?')} frames (nominal {1000 * wand.get('length_m', 0):.1f} mm)")
    word, reasons = verdict(doc.get("verdict"))
    out = [f'<p class="meta">{_e(line)}</p>' for line in lines]
    out.append(f'<p id="rig-verdict">Rig verdict: {_verdict_html(word)}'
               + (f" \u2014 {_e('; '.join(reasons))}" if reasons else "") + "</p>")
    verdict_doc = doc.get("verdict")
    v = verdict_doc if isinstance(verdict_doc, dict) else {}
    near = [e for e in v.get("at_limit") or [] if isinstance(e, dict) and e.get("levels", [None, None])[1] == "poor"]
    if near:  # within one standard error of the limit of poor: the better level holds
        out.append('<p id="at-limit">At the limit, within one standard error (the better level holds):'
                   + _items([f"{e['camera'] + ' ' if e.get('camera') else ''}{e['criterion']} {at_limit_text(e)}"
                             for e in near]) + "</p>")
    faults = v.get("faults")
    words = [f"{_e(FAULT_WORDS.get(str(f.get('kind')), f.get('kind')))}{_e(' (' + f['camera'] + ')') if f.get('camera') else ''}: "
             f"{_e(f.get('message', ''))}" for f in faults or [] if isinstance(f, dict)]
    out.append('<p id="rig-faults">Faults: ' + (DASH if faults is None else "none found" if not words else "")
               + ('<ul>' + "".join(f"<li>{w}</li>" for w in words) + "</ul>" if words else "") + "</p>")
    limits = _limit_items(v.get("limits") or [], len(doc.get("cameras") or []))
    if limits:  # the intrinsics given, not refined, that a camera's position hinges on (not faults)
        out.append('<div id="rig-limits">What limits the cameras\' positions (intrinsics given, not refined):'
                   + _items(limits) + "</div>")
    if _advice_of(v):
        out.append('<div id="rig-advice">What to do:' + _items(_advice_of(v)) + "</div>")
    placement = world.get("placement")
    place = placement if isinstance(placement, dict) else {}
    p_word, p_reasons = verdict(v.get("placement"))
    if world.get("scale") == "arbitrary" or world.get("frame") == "wand_volume":  # older results graded it all the same
        out.append(f'<p id="placement">World frame: {_e(NO_SCALE if world.get("scale") == "arbitrary" else NO_REFERENCE)}</p>')
        return out
    out.append(f'<p id="placement">World frame placement: origin \u00b1 {_num(place.get("origin_std_mm"), ".2f", " mm")}'
               f', axes \u00b1 {_num(place.get("axes_std_deg"), ".3f", " deg")}'
               + (f" \u2014 {_verdict_html(p_word)}" + (f" ({_e('; '.join(p_reasons))})" if p_reasons else "")
                  if p_word else "") + "</p>")
    return out


def _limit_items(limits: list, n_cameras: int) -> list[str]:
    """The verdict's limits as the CLI summary says them (:func:`wandcal.calib.judge.limit_words.limit_lines`),
    each group's "to do" in its own item."""
    items: list[str] = []
    for line in limit_lines(limits, n_cameras):
        if line.startswith("    to do:") and items:
            items[-1] += " \u2014 " + line.strip()
        else:
            items.append(line.strip())
    return items


def _advice_of(value) -> list[str]:
    advice = value.get("advice") if isinstance(value, dict) else None
    return [str(a) for a in advice] if isinstance(advice, list) else []


def _items(items: list[str]) -> str:
    return ("<ul>" + "".join(f"<li>{_e(i)}</li>" for i in items) + "</ul>") if items else ""


def _advice(data: ReportData) -> list[str]:
    if not data.has_capture:
        return []
    items = data.advice
    empty = (f"Nothing to do: every camera saw the wand over at least {COVERAGE_GOAL:.0%} of its image, and no "
             "residual pattern stands out.")
    return _list("advice", "What to do", items, empty)


def _list(section_id: str, title: str, items: list[str], empty: str) -> list[str]:
    body = ("<ul>" + "".join(f"<li>{_e(i)}</li>" for i in items) + "</ul>") if items else f"<p>{_e(empty)}</p>"
    return [f'<section id="{section_id}" class="{section_id}"><h2>{_e(title)}</h2>{body}</section>']


def _overview(data: ReportData) -> str:
    unit = data.unit
    head = ["camera", f"centre x, y, z ({unit})", "reprojection RMS (px)", "observations", "centre \u00b1 (mm)",
            "rotation \u00b1 (deg)", "geometry \u00b1 (mm)", "geometry rotation \u00b1 (deg)", "ray distance (mm)",
            "outliers", "verdict", "coverage"]
    rows = []
    for cam in data.cameras:
        d = cam.doc
        word, _ = verdict(d.get("verdict"))
        rows.append(
            f'<tr data-camera="{_e(cam.id)}"><td><a href="#camera-{_e(cam.id)}">{_e(cam.id)}</a></td>'
            f'<td class="num">{_e(", ".join(f"{v:.3f}" for v in d["center"]))}</td>'
            f'<td class="num">{_num(d.get("reprojection_rms_px"), ".3f")}</td>'
            f'<td class="num">{_num(d.get("observations"), "d")}</td>'
            f'<td class="num">{_num(d.get("center_std_mm"), ".2f")}</td>'
            f'<td class="num">{_num(d.get("rotation_std_deg"), ".4f")}</td>'
            f'<td class="num">{_num(d.get("geometry_std_mm"), ".2f")}</td>'
            f'<td class="num">{_num(d.get("geometry_rotation_std_deg"), ".4f")}</td>'
            f'<td class="num">{_num(d.get("residual_mm"), ".2f")}</td>'
            f'<td class="num">{_num(d.get("outlier_share"), ".1%")}</td>'
            f"<td>{_verdict_html(word)}</td>"
            f'<td class="num">{_num(coverage(cam), ".0%")}</td></tr>')
    return _table(head, rows)


def _offsets(sync) -> list[str]:
    """The cameras' time offsets (a result of ``--sync auto``, docs/sync.md): each camera's offset
    against the reference with its standard error, in frames and milliseconds, and the cameras
    found out of time; nothing for a result without them."""
    if not isinstance(sync, dict) or not isinstance(sync.get("cameras"), list):
        return []
    rate = sync.get("rate_hz")
    drift = any(isinstance(c, dict) and c.get("drift_ppm") is not None for c in sync["cameras"])
    head = ["camera", "offset (frames)", "± (frames)", "offset (ms)", "± (ms)"]
    head += ["drift (ppm)", "± (ppm)"] if drift else []
    head.append("")
    rows = []
    for c in (c for c in sync["cameras"] if isinstance(c, dict)):
        std = c.get("offset_std_frames")
        note = ("reference" if c.get("id") == sync.get("reference") else "out of time" if c.get("out_of_time")
                else "whole frames only" if std is None else "")
        cells = [_num(c.get("offset_frames"), "+.3f"), _num(std, ".3f"),
                 _num(1000 * c["offset_frames"] / rate if rate and _finite(c.get("offset_frames")) else None, "+.2f"),
                 _num(1000 * std / rate if rate and _finite(std) else None, ".2f")]
        cells += [_num(c.get("drift_ppm"), "+.1f"), _num(c.get("drift_std_ppm"), ".1f")] if drift else []
        mark = ' class="out-of-time"' if c.get("out_of_time") else ""
        rows.append(f'<tr data-camera="{_e(c.get("id", "?"))}"{mark}>'
                    f"<td>{_e(c.get('id', '?'))}</td>" + "".join(f'<td class="num">{x}</td>' for x in cells)
                    + f"<td>{_e(note)}</td></tr>")
    late = [c.get("id", "?") for c in sync["cameras"] if isinstance(c, dict) and c.get("out_of_time")]
    said = (f"Found out of time, against what the frame numbers (or timestamps) said: {', '.join(late)}; their frames "
            "were realigned by the wand." if late else "No camera was found out of time.")
    unit = "" if rate else " The frame rate is unknown, so the offsets are in frames only."
    return ['<section id="sync"><h2>Time offsets</h2>',
            f"<p>Each camera's frame k was exposed at {_e(sync.get('reference', '?'))}'s frame k + its offset "
            f"(found from the wand, docs/sync.md), ± one standard error. {_e(said)}{_e(unit)}</p>",
            _table(head, rows), "</section>"]


def _finite(value: object) -> TypeGuard[float]:
    """A finite number (int or float) in a result's JSON."""
    return isinstance(value, (int, float)) and math.isfinite(value)


def _camera_section(data: ReportData, cam: CameraSummary, figure: str | None) -> list[str]:
    d = cam.doc
    word, reasons = verdict(d.get("verdict"))
    worst = d.get("worst_frames") or []
    fields = [
        ("centre x, y, z", f"{', '.join(f'{v:.4f}' for v in d['center'])} {data.unit}"),
        ("reprojection RMS", _num(d.get("reprojection_rms_px"), ".3f", " px")),
        ("observations (wand ends)", _num(d.get("observations"), "d")),
        ("frames with both ends in the solve", _num(d.get("frames_with_both_ends"), "d")),
        ("point-track RMS", _num(d.get("point_rms_px"), ".3f", " px")),
        ("point observations", _num(d.get("point_observations"), "d")),
        ("centre standard deviation (center_std_mm)", _num(d.get("center_std_mm"), ".2f", " mm")),
        ("rotation standard deviation (rotation_std_deg)", _num(d.get("rotation_std_deg"), ".4f", " deg")),
        ("centre relative to the other cameras (geometry_std_mm)", _num(d.get("geometry_std_mm"), ".2f", " mm")),
        ("rotation relative to the other cameras (geometry_rotation_std_deg)",
         _num(d.get("geometry_rotation_std_deg"), ".4f", " deg")),
        ("ray distance in the volume (residual_mm)", _num(d.get("residual_mm"), ".2f", " mm")),
        ("outliers (outlier_share)", _num(d.get("outlier_share"), ".1%")),
        ("verdict", _verdict_html(word) + _items(reasons + _advice_of(d.get("verdict")))),
        ("coverage of the image", _num(coverage(cam), ".0%")
         + (f" (no samples in {_e(', '.join(d['uncovered']))})" if d.get("uncovered") else "")),
        ("first pose from", _e(d.get("initial_pose") or DASH)),
        ("worst frames", _e(", ".join(f"{w['frame']} ({w['error_px']:.2f} px)" for w in worst)) or DASH),
    ]
    if not any("point_observations" in c for c in data.result.doc["cameras"]):  # a capture without points.csv
        fields = [(k, v) for k, v in fields if not k.startswith("point")]
    rows = [f"<tr><th>{_e(k)}</th><td>{v}</td></tr>" for k, v in fields]
    own = d.get("warnings")  # its own in full; the result's warnings fold those several cameras share
    said = cam.advice + ([str(w) for w in own] if isinstance(own, list) else
                         [w for w in data.result.doc.get("warnings") or [] if names_camera(w, cam.id)])
    out = [f'<section class="camera" id="camera-{_e(cam.id)}" data-camera="{_e(cam.id)}"><h2>{_e(cam.id)}</h2>',
           "<table>" + "".join(rows) + "</table>"]
    if said:
        out.append('<ul class="advice">' + "".join(f"<li>{_e(s)}</li>" for s in said) + "</ul>")
    if figure:
        out.append(_img(figure, _camera_alt(cam)))
        out.append(f'<p class="caption">{_e(camera_caption(cam))}</p>')
    out.append("</section>")
    return out


# -- captions: worded from what each figure draws (the colours' names come with the colours) --
def rig_caption(data: ReportData) -> str:
    drawn = []
    if len(data.trajectory):
        drawn.append(f"{WAND_DOTS[1]} dots are the wand's midpoint in each frame ({len(data.trajectory)} frames)")
    if len(data.points):
        drawn.append(f"{POINT_DOTS[1]} dots are the single-point tracks ({len(data.points)} points)")
    if data.static_markers is not None:
        drawn.append("black squares are the static object's markers")
    if data.axis:
        drawn.append(f"{AXIS_POINTS[1]} diamonds are the axis points ({', '.join(data.axis)})")
    samples = (_sentence("; ".join(drawn)) + " ") if drawn else ""
    return ("Each camera is a frustum in its own colour pointing where it looks, its thick edge the top of its "
            f"image, its id beside it (with a line to it when the id had to move aside). {samples}The red, green "
            "and blue lines are the world's x, y and z axes at its origin.")


def camera_caption(cam: CameraSummary) -> str:
    seen = "white dots its wand ends" + (f", {POINT_DOTS[1]} dots its single points" if len(cam.point_uv) else "")
    outliers = (f"; {OUTLIER_CROSSES[1]} crosses are outliers, left out of the cells"
                if cam.outlier.any() or cam.point_outlier.any() else "")
    return (f"Left: how many samples it saw in each cell of its image (pale red: none), {seen}. Middle: the RMS "
            "residual per cell, with arrows of the mean residual (a pattern of arrows means a systematic error, "
            f"not noise){outliers}. Right: the residuals' histogram, stacked by kind, against what Gaussian noise "
            "would give (black line); the dashed line is the camera's reprojection RMS, the result's figure (its wand "
            "ends the solve kept), as in the table above.")


def wand_caption(data: ReportData) -> str:
    outliers = (" Red crosses are frames with an outlier observation or a length far off the others (triangles: off "
                "the scale, drawn at its edge)." if data.outlier_frame.any() else "")
    nominal = " The dashed line is the wand's nominal length." if (data.result.doc.get("wand") or {}).get("length_m") else ""
    return ("Each wand end triangulated on its own, without the known length: its spread is an independent check "
            f"of the calibration (easyWand's wand score is std / mean). {FRAME_DOTS[1].capitalize()} dots are the "
            f"frames, the histogram beside them their lengths.{outliers}{nominal}")


def _sentence(text: str) -> str:
    return text[:1].upper() + text[1:] + "."


def coverage(cam: CameraSummary) -> float | None:
    """The share of the camera's image its observations cover: the result's own (what its verdict
    judged: wand ends and single points the calibration used), else the capture's wand ends."""
    value = cam.doc.get("coverage")
    return value if isinstance(value, (int, float)) else cam.covered


def verdict(value) -> tuple[str | None, list[str]]:
    """(word, reasons) of a result's ``verdict``, whichever shape it has: a word, or an object
    with the word under ``verdict``/``grade``/``level`` and a ``reasons`` list; (None, []) when absent."""
    if isinstance(value, str):
        return value, []
    if isinstance(value, dict):
        word = next((value[k] for k in ("verdict", "grade", "level", "rating") if isinstance(value.get(k), str)), None)
        reasons = value.get("reasons") or []
        return word, [str(r) for r in reasons] if isinstance(reasons, list) else [str(reasons)]
    return None, []


def _verdict_html(word: str | None) -> str:
    if not word:
        return DASH
    return f'<span class="verdict-{_e(word.lower())}">{_e(word)}</span>'


def _num(value, fmt: str, suffix: str = "") -> str:
    if value is None or isinstance(value, bool) or (isinstance(value, float) and not math.isfinite(value)):
        return DASH
    try:
        return _e(format(value, fmt) + suffix)
    except (TypeError, ValueError):
        return DASH


def _table(head: list[str], rows: list[str]) -> str:
    return "<table><tr>" + "".join(f"<th>{_e(h)}</th>" for h in head) + "</tr>" + "".join(rows) + "</table>"


def _img(name: str | None, alt: str) -> str:
    return f'<p><img src="{_e(name)}" alt="{_e(alt)}"></p>' if name else ""


def _rig_alt(data: ReportData) -> str:
    ids = camera_list([c.id for c in data.cameras], len(data.cameras))  # "all 64 cameras" on a big rig
    who = f"cameras {ids}" if len(data.cameras) <= LISTED_CAMERAS else ids
    extra = f", the wand's path over {len(data.trajectory)} frames" if len(data.trajectory) else ""
    return f"The rig in 3D and from above: {who} as frusta with their ids{extra}, and the world axes."


def _wand_alt(data: ReportData) -> str:
    return (f"The wand's length over {len(data.wand_frames)} frames, {int(data.outlier_frame.sum())} of them "
            "marked as outliers, with a histogram of the lengths.")


def _camera_alt(cam: CameraSummary) -> str:
    rms = cam.doc.get("reprojection_rms_px")
    return (f"{cam.id}: where in its image the wand was seen ({_num(cam.covered, '.0%')} of the cells), its "
            f"residuals over the image and their histogram (RMS {_num(rms, '.2f')} px).")


def _e(text) -> str:
    return html.escape(str(text), quote=True)
