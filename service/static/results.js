// The Rig panel's words and numbers: each camera's pose, its two uncertainties (in the world
// frame, and relative to the other cameras), its residuals and verdict; the rig's verdict, its
// named faults, its advice and how well the world frame is placed. Older results lack some of
// these fields: a dash then.
import { el } from "./dom.js";

export const DASH = "–";  // what a field an older result lacks shows
const FAULT_WORDS = {  // wandcal-result/1 verdict.faults[].kind, for people
  intrinsics: "intrinsics", timing: "timing", wand_scale: "wand scale", outliers: "outliers",
  unconverged: "not converged", undetermined: "undetermined",
};

const num = (v, digits, scale = 1) => (typeof v === "number" && Number.isFinite(v) ? (v * scale).toFixed(digits) : DASH);
const level = (v) => (v && typeof v.level === "string" ? v.level : null);
const words = (v) => [...((v && v.reasons) || []), ...((v && v.advice) || [])].join("\n");

// (header, tooltip, cell) of each column of the camera table
const COLUMNS = [
  ["camera", "", (c) => c.id],
  ["centre x, y, z (m)", "the camera's centre in the world frame", (c) => c.center.map((v) => v.toFixed(3)).join(", ")],
  ["± (mm)", "predicted 1σ of the centre in the world frame (center_std_mm): the camera relative to the rig plus the world frame's own placement", (c) => num(c.center_std_mm, 2)],
  ["± (deg)", "predicted 1σ of the rotation in the world frame (rotation_std_deg)", (c) => num(c.rotation_std_deg, 3)],
  ["geometry ± (mm)", "1σ of the centre relative to the other cameras, gauge-free (geometry_std_mm): what 3D accuracy depends on", (c) => num(c.geometry_std_mm, 2)],
  ["geometry ± (deg)", "1σ of the rotation relative to the other cameras (geometry_rotation_std_deg)", (c) => num(c.geometry_rotation_std_deg, 3)],
  ["RMS (px)", "reprojection RMS of its wand observations", (c) => num(c.reprojection_rms_px, 3)],
  ["ray distance (mm)", "RMS distance of its rays from the triangulated points in the volume (residual_mm)", (c) => num(c.residual_mm, 2, 1)],
  ["outliers", "share of its observations judged gross outliers (outlier_share)", (c) => (typeof c.outlier_share === "number" ? `${(100 * c.outlier_share).toFixed(1)}%` : DASH)],
  ["observations", "wand ends (and single points) it saw that the solve used", (c) => (c.observations != null ? c.observations : DASH)],
];

export function cameraTable(result) {
  const head = el("thead", {}, el("tr", {}, ...COLUMNS.map(([h, tip]) => el("th", tip ? { title: tip } : {}, h)),
    el("th", { title: "excellent / good / poor, with the reasons and what to do (hover)" }, "verdict")));
  const rows = result.cameras.map((c) => {
    const v = c.verdict, lv = level(v);
    return el("tr", { "data-camera": c.id }, ...COLUMNS.map(([, , cell]) => el("td", {}, cell(c))),
      el("td", { class: lv ? `verdict-${lv}` : "", title: words(v) }, lv || DASH));
  });
  return [head, el("tbody", {}, ...rows)];
}

// The rig's verdict, its faults (each naming its camera, if one), its advice and the world's placement.
export function rigJudgement(result) {
  const v = result.verdict, lv = level(v);
  const out = [el("p", { id: "verdict" }, ...(lv ? [el("strong", { class: `verdict-${lv}` }, `verdict: ${lv}`),
    ...(v.reasons && v.reasons.length ? [` (${v.reasons.join("; ")})`] : [])] : [`verdict: ${DASH}`]))];
  // criteria within one standard error of the limit of poor: the better level holds (docs/verdict.md)
  const near = ((v && Array.isArray(v.at_limit)) ? v.at_limit : []).filter((e) => e && e.levels && e.levels[1] === "poor");
  if (near.length) out.push(el("p", { id: "at-limit" }, "at the limit, within one standard error (the better level holds): ",
    near.map((e) => `${e.camera ? `${e.camera} ` : ""}${e.criterion} ${e.value} ± ${e.std} ${e.unit} against ${e.limit} ${e.unit}`).join("; ")));
  const faults = (v && Array.isArray(v.faults)) ? v.faults : [];
  out.push(el("h3", {}, "Faults"), faults.length
    ? el("ul", { id: "faults" }, ...faults.map((f) => el("li", { "data-kind": f.kind, "data-camera": f.camera || "" },
      el("strong", {}, `${FAULT_WORDS[f.kind] || f.kind}${f.camera ? ` (${f.camera})` : ""}: `), f.message || "")))
    : el("p", { id: "faults", class: "muted" }, v && Array.isArray(v.faults) ? "none found" : DASH));
  const advice = (v && v.advice) || [];
  if (advice.length) out.push(el("h3", {}, "What to do"), el("ol", { id: "rig-advice" }, ...advice.map((a) => el("li", {}, a))));
  const world = result.world || {}, placement = world.placement, pv = v && v.placement, plv = level(pv);
  if (world.scale === "arbitrary" || world.frame === "wand_volume") {  // no object placed the world: nothing to grade
    out.push(el("p", { id: "placement" }, el("strong", {}, "world frame: "), world.scale === "arbitrary"
      ? "no world reference and no scale (point tracks only): an arbitrary frame, up to scale"
      : "no world reference (no static.csv, no axis points): the wand volume's own frame, an arbitrary one"));
    return out;
  }
  out.push(el("p", { id: "placement" }, el("strong", {}, "world frame placement: "),
    `origin ± ${num(placement && placement.origin_std_mm, 2)} mm, axes ± ${num(placement && placement.axes_std_deg, 3)} deg`,
    ...(plv ? [" · ", el("span", { class: `verdict-${plv}` }, plv), ...(pv.reasons && pv.reasons.length ? [` (${pv.reasons.join("; ")})`] : [])] : [])));
  return out;
}

// The cameras' time offsets of a result of --sync auto (docs/sync.md): each camera's offset from the
// reference ± its standard error, in frames and in ms where the rate is known, the cameras found out
// of time marked; nothing (the table hidden) for a result without them.
export function offsetsTable(result) {
  const sync = result.sync;
  if (!sync || !Array.isArray(sync.cameras)) return [];
  const rate = typeof sync.rate_hz === "number" && sync.rate_hz > 0 ? sync.rate_hz : null;
  const drift = sync.cameras.some((c) => c.drift_ppm != null);
  const signed = (v, digits, scale = 1) => (typeof v === "number" ? `${v >= 0 ? "+" : ""}${num(v, digits, scale)}` : DASH);
  const head = ["camera", "offset (frames)", "± (frames)", ...(rate ? ["offset (ms)", "± (ms)"] : []),
    ...(drift ? ["drift (ppm)", "± (ppm)"] : []), ""];
  const rows = sync.cameras.map((c) => {
    const note = c.id === sync.reference ? "reference" : c.out_of_time ? "out of time"
      : c.offset_std_frames == null ? "whole frames only" : "";
    const cells = [c.id, signed(c.offset_frames, 3), num(c.offset_std_frames, 3),
      ...(rate ? [signed(c.offset_frames, 2, 1000 / rate), num(c.offset_std_frames, 2, 1000 / rate)] : []),
      ...(drift ? [signed(c.drift_ppm, 1), num(c.drift_std_ppm, 1)] : []), note];
    return el("tr", { "data-camera": c.id, class: c.out_of_time ? "out-of-time" : "" }, ...cells.map((x) => el("td", {}, x)));
  });
  const late = sync.cameras.filter((c) => c.out_of_time).map((c) => c.id);
  return [el("caption", {}, `Time offsets against ${sync.reference}, ± 1 standard error` + (rate ? "" : " (frame rate unknown: frames only)")
    + (late.length ? ` · out of time: ${late.join(", ")}` : "")),
  el("thead", {}, el("tr", {}, ...head.map((h) => el("th", {}, h)))), el("tbody", {}, ...rows)];
}
