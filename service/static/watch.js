// The live capture's camera health (GET /watch/live, issue 36): each camera's status, residual and
// the sequential test's statistic against its threshold, updated as the take runs; the re-solve of
// a moved camera (POST /watch/live/resolve) once the take is stored.
import { $, el } from "./dom.js";

const STATUS_WORDS = { ok: "ok", moved: "moved", drifting: "drifting", one_of: "moved (or another)" };

// The test's statistic as a bar: full at the threshold, red past it.
function statisticBar(value, threshold) {
  const bar = el("span", { class: "bar", title: `${value.toFixed(1)} of ${threshold}` }, el("span"));
  bar.firstChild.style.width = Math.min(100, Math.round((100 * value) / threshold)) + "%";
  if (value > threshold) bar.classList.add("over");
  return bar;
}

function movedText(c) {
  if (c.status === "ok") return "";
  if (c.status === "one_of") return c.message || `one of ${c.one_of.join(", ")} moved; the take cannot tell which`;
  const how = c.kind === "drift" ? `drifting over ${c.drift_frames} frames from frame ${c.moved_at_frame}`
    : c.before_take ? "moved before the take began" : `knocked at frame ${c.moved_at_frame}`;
  return `${how}, named at frame ${c.detected_at_frame}`;
}

// doc: GET /watch/live; resolve: the re-solve's watch (GET /watch/{id}) or null
export function renderWatch(doc, liveState, shownJob, resolve) {
  const box = $("#live-watch");
  const running = ["running", "stopping", "waiting_for_wand"].includes(liveState);
  box.hidden = doc.state === "idle" && !(running && shownJob);
  box.dataset.state = doc.state;
  $("#watch-start").hidden = doc.state !== "idle" || !running || !shownJob;
  $("#watch-start").textContent = `Watch camera health against job ${(shownJob || "").slice(0, 8)}'s result`;
  $("#watch-state").textContent = doc.state === "idle" ? "" : doc.state === "watching" ? "· updating" : `· ${doc.state}`;
  $("#watch-error").hidden = !doc.error;
  $("#watch-error").textContent = doc.error || "";
  const report = doc.report;
  $("#watch-table").hidden = !report;
  if (!report) { $("#watch-summary").textContent = doc.state === "watching" ? "waiting for the first 200 frames…" : ""; }
  else {
    $("#watch-summary").textContent = `${report.frames} frames (${report.first_frame}–${report.last_frame}), `
      + `${(report.markers / Math.max(1, report.frames)).toFixed(1)} markers a frame; against ${doc.standing}`
      + behindText(doc, report);
    $("#watch-table tbody").replaceChildren(...report.cameras.map((c) => el("tr",
      { "data-watch-camera": c.id, "data-status": c.status },
      el("td", {}, c.id), el("td", { class: "health-" + c.status }, STATUS_WORDS[c.status] || c.status),
      el("td", {}, c.residual_px.toFixed(3)), el("td", {}, `${Math.round(100 * c.matched)}%`),
      el("td", {}, statisticBar(c.statistic != null ? c.statistic : c.peak || 0, doc.threshold)),
      el("td", {}, movedText(c)))));
  }
  const moved = report ? report.moved : [];
  $("#watch-moved").hidden = !moved.length;
  $("#watch-moved").textContent = !moved.length ? ""
    : doc.state === "done" ? `${moved.join(", ")} moved: re-solve ${moved.length > 1 ? "them" : "it"} from this take's markers (no wand).`
    : `${moved.join(", ")} moved: stop the take to re-solve ${moved.length > 1 ? "them" : "it"} from its markers.`;
  $("#watch-resolve").hidden = !(moved.length && doc.state === "done") || !!resolve;
  $("#watch-resolve").textContent = `Re-solve ${moved.join(", ")}`;
  renderResolve(resolve);
}

// a watch that trails the recording by more than the batch it waits to fill says by how much: on a busy
// machine it catches up batch by batch
function behindText(doc, report) {
  const behind = (doc.recorded_frame ?? report.last_frame) - report.last_frame;
  return doc.state === "watching" && behind > doc.batch_frames ? `; ${behind} frames behind the recording` : "";
}

function renderResolve(w) {
  const box = $("#watch-resolved");
  box.hidden = !w;
  if (!w) return;
  box.dataset.state = w.state;
  if (w.state === "failed" || w.state === "cancelled") { box.replaceChildren(el("span", { class: "error" }, w.error || w.state)); return; }
  if (w.state !== "done") { box.replaceChildren(`re-solving… ${(w.progress && w.progress.message) || w.state}`); return; }
  const lines = w.report.cameras.filter((c) => c.resolved_points != null).map((c) => el("li", { "data-resolved": c.id },
    `${c.id}: moved ${c.translation_mm.toFixed(2)} mm (σ ${c.center_std_mm.toFixed(2)}) and turned `
    + `${c.rotation_deg.toFixed(3)}° (σ ${c.rotation_std_deg.toFixed(3)}), from ${c.resolved_points} markers at `
    + `${c.resolved_rms_px.toFixed(2)} px`));
  // a moved camera the take could not re-solve says why and what to record (the report's not_resolved)
  const unsolved = w.report.cameras.filter((c) => c.not_resolved).map((c) => el("li", { "data-not-resolved": c.id },
    `${c.id}: not re-solved: ${c.not_resolved}`));
  box.replaceChildren(el("ul", {}, ...lines, ...unsolved), el("a", { href: `/api/v1/watch/${w.id}/result`, target: "_blank",
    rel: "noopener", download: `wandcal-watch-${w.id.slice(0, 8)}.json` }, "the updated result (wandcal-result/1)"));
}
