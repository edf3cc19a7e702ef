// The rig page: polls the API once a second and draws what it finds. Nothing from elsewhere: the
// 3D view's library is vendored (static/vendor/).
import { checkPanel } from "./checks.js";
import { $, el } from "./dom.js";
import { cameraTable, offsetsTable, rigJudgement } from "./results.js";
import { RigView } from "./rigview.js";
import { renderWatch } from "./watch.js";

const API = "/api/v1";
const POLL_MS = 1000;  // progress is written every 0.2 s; once a second is enough for people
const CLOCK_SLACK_S = 2;  // the Date header has whole seconds: a smaller difference is its rounding, not skew
let token = new URLSearchParams(location.hash.slice(1)).get("token") || localStorage.getItem("wandcal-token") || "";
// links opened in a tab of their own (a job's report) cannot send the Authorization header: the
// server also takes the token from this cookie, for reads only (service/api/deps.py)
const setTokenCookie = () => {
  document.cookie = `wandcal_token=${encodeURIComponent(token)}; path=${API}; SameSite=Strict`
    + (token ? "" : "; max-age=0");
};
setTokenCookie();
let shownJob = null;  // the job the Rig panel shows
let loadingJob = null;  // the job being fetched for the panel: a poll does not load it twice (each load resets the view)
let followNewest = true;  // the panel moves on to each newer finished job, until someone picks one with "show"
let serverSkewS = 0;  // server clock minus this browser's, from the Date header: wait_deadline is server time
const SIGMA_HISTORY = 120;  // guidance updates kept per camera for its sparkline: two minutes at one a second
const sigmaHistory = new Map();  // "capture/camera" -> the predicted centre sigmas seen so far (mm)
const SVG = "http://www.w3.org/2000/svg";
const SOURCE_WORDS = { upload: "uploaded", replay: "recorded folder", stream: "streamed", live: "live capture" };
let resolveWatch = null;  // the re-solve's watch id (POST /watch/live/resolve), shown under the health table
let rigView = null;  // made when the first result is shown: the section is hidden until then

const short = (id) => id.slice(0, 8);

async function api(path, options = {}) {
  const headers = Object.assign({}, options.headers || {});
  if (token) headers.Authorization = "Bearer " + token;
  const response = await fetch(API + path, Object.assign({}, options, { headers }));
  const skew = (Date.parse(response.headers.get("Date")) - Date.now()) / 1000;
  serverSkewS = Math.abs(skew) > CLOCK_SLACK_S ? skew : 0;
  if (response.status === 401) {
    $("#token-box").hidden = false;
    throw new Error("this server needs its bearer token");
  }
  const body = await response.json();
  if (!response.ok) throw new Error(body.detail || response.statusText);
  return body;
}

function coverage(capture) {
  const most = Math.max(1, capture.frames);
  return capture.coverage.map((c) => {
    const pct = Math.round((100 * c.pairs) / most);
    const bar = el("span", { class: "bar", title: `${c.pairs} of ${capture.frames} frames` }, el("span"));
    bar.firstChild.style.width = pct + "%";
    return el("span", { class: "cov", "data-camera": c.id, "data-pairs": c.pairs }, `${c.id} ${c.pairs}`, bar);
  });
}

// "live capture: cam1 cam2", not "live (live: cam1 cam2)": the name without its source's prefix
function sourceText(c) {
  const source = SOURCE_WORDS[c.source] || c.source;
  const name = (c.name || "").replace(new RegExp(`^${c.source}:\\s*`), "");
  return name && name !== c.source ? `${source}: ${name}` : source;
}

function renderCaptures(captures) {
  const body = $("#captures tbody");
  body.replaceChildren(...captures.map((c) => {
    const run = el("button", { onclick: () => startJob(c.id) }, "calibrate");
    const check = el("button", { class: "check", disabled: shownJob === null, onclick: (e) => runCheck(c.id, e.currentTarget),
      title: shownJob === null ? "a result is needed first: calibrate a capture"
        : `did a camera move? this capture judged against the result in the Rig panel (job ${short(shownJob)})` }, "check");
    return el("tr", { "data-capture-id": c.id },
      el("td", { class: "id", title: c.id }, short(c.id)), el("td", {}, sourceText(c)),
      el("td", {}, c.frames), el("td", {}, ...coverage(c)), el("td", {}, run, " ", check));
  }));
  $("#no-captures").hidden = captures.length > 0;
}

function progressText(job) {
  if (job.state === "failed" || job.state === "cancelled") return el("span", { class: "error" }, job.error || job.state);
  const p = job.progress || {};
  const parts = [p.stage, p.iteration != null ? `iteration ${p.iteration}` : null,
    p.cost != null ? `cost ${Number(p.cost).toPrecision(4)}` : null, p.message].filter(Boolean);
  return parts.join(" · ");
}

function renderJobs(jobs) {
  $("#jobs tbody").replaceChildren(...jobs.map((j) => {
    const action = j.state === "done" ? el("button", { onclick: () => { followNewest = false; showResult(j.id); } }, "show")
      : ["queued", "running"].includes(j.state) ? el("button", { onclick: () => cancelJob(j.id) }, "cancel") : "";
    // the illustrated report (drawn by the server on the first visit), in a tab of its own
    const report = j.state === "done" ? [" ", el("a", { href: `${API}/jobs/${j.id}/report`, target: "_blank",
      rel: "noopener", class: "report" }, "report")] : [];
    return el("tr", { "data-job-id": j.id, "data-state": j.state },
      el("td", { class: "id", title: j.id }, short(j.id)), el("td", { class: "id" }, short(j.capture_id)),
      el("td", {}, j.method), el("td", { class: "state-" + j.state }, j.state), el("td", {}, progressText(j)),
      el("td", {}, j.attempts), el("td", {}, action, ...report));
  }));
  // jobs come newest first: the panel follows the newest finished job, and says when a newer one runs
  const latest = jobs.find((j) => j.state === "done");
  if (latest && latest.id !== loadingJob && (shownJob === null || (followNewest && latest.id !== shownJob))) {
    showResult(latest.id);
  }
  const newer = jobs.findIndex((j) => j.id === shownJob);
  const pending = jobs.slice(0, Math.max(newer, 0)).find((j) => ["queued", "running"].includes(j.state));
  $("#result-newer").textContent = pending ? `· job ${short(pending.id)} is ${pending.state}; the panel moves to it when it is done` : "";
}

async function startJob(captureId) {
  try {
    await api("/jobs", { method: "POST", headers: { "Content-Type": "application/json" },
      body: JSON.stringify({ capture_id: captureId }) });  // the server's default method
    followNewest = true;
    poll();
  } catch (err) { alert(err.message); }
}

// the capture judged against the shown result; a moved camera's re-solve is offered under it
async function runCheck(captureId, button) {
  const jobId = shownJob;
  button.disabled = true;
  const section = $("#check-section");
  try {
    const answer = await api(`/captures/${captureId}/check`, { method: "POST",
      headers: { "Content-Type": "application/json" }, body: JSON.stringify({ job_id: jobId }) });
    $("#check-body").replaceChildren(...checkPanel(answer, `job ${short(jobId)}`, (moved) => resolveMoved(captureId, jobId, moved)));
    section.dataset.captureId = captureId;
  } catch (err) {
    $("#check-body").replaceChildren(el("p", { class: "error" }, err.message));
  }
  section.hidden = false;
  button.disabled = false;
}

async function resolveMoved(captureId, jobId, moved) {
  try {
    const job = await api("/jobs", { method: "POST", headers: { "Content-Type": "application/json" },
      body: JSON.stringify({ capture_id: captureId, options: { from_job: jobId, solve_only: moved } }) });
    $("#check-section").dataset.resolveJob = job.id;
    followNewest = true;
    poll();
  } catch (err) { alert(err.message); }
}

async function cancelJob(jobId) {
  try { await api(`/jobs/${jobId}`, { method: "DELETE" }); poll(); } catch (err) { alert(err.message); }
}

function minutes(seconds) {
  const s = Math.max(0, Math.round(seconds));
  return `${Math.floor(s / 60)}:${String(s % 60).padStart(2, "0")}`;
}

// The live capture (GET /capture). Its buttons are in the HTML and only shown or hidden, so a
// click is never lost to a poll replacing the node under the pointer.
function renderLive(s) {
  $("#live").dataset.state = s.state;
  $("#live-state").textContent = s.state.replaceAll("_", " ");
  $("#live-state").className = "state-" + s.state;
  $("#live-idle").hidden = s.state !== "idle";
  $("#live-run").hidden = s.state === "idle";
  if (s.state === "idle") return;
  $("#live-phase").textContent = s.phase || s.state;
  $("#live-frames").textContent = `${s.frames_recorded} / ${s.frames_total} frame sets`;
  $("#live-bar").style.width = Math.round((100 * s.frames_recorded) / Math.max(1, s.frames_total)) + "%";
  $("#live-fps").textContent = `${Number(s.fps).toFixed(1)} fps`;
  $("#live-capture").textContent = s.capture_id ? `capture ${short(s.capture_id)}` : "";
  const waiting = s.state === "waiting_for_wand";
  $("#live-wait").hidden = !waiting;
  if (waiting) {
    $("#live-prompt").textContent = s.prompt || "";
    const left = s.wait_deadline - (Date.now() / 1000 + serverSkewS);
    $("#live-left").textContent = minutes(left);
    $("#live-left").dataset.seconds = Math.max(0, Math.round(left));
  }
  $("#live-continue").hidden = !waiting;
  $("#live-stop").hidden = !["running", "waiting_for_wand"].includes(s.state);
  $("#live-error").hidden = !s.error;
  $("#live-error").textContent = s.error || "";
  $("#live-dropped tbody").replaceChildren(...s.cameras.map((id) => el("tr", { "data-camera": id },
    el("td", {}, id), el("td", { class: s.dropped[id] ? "error" : "" }, s.dropped[id] || 0))));
  $("#live-messages").replaceChildren(...s.messages.map((m) => el("li", {}, m)));
  const autostop = $("#live-autostop");
  autostop.checked = !!s.stop_when_enough;
  autostop.disabled = !["running", "waiting_for_wand"].includes(s.state) || s.enough == null;
}

// The coverage grid of one camera: a cell per grid cell, filled where the wand has been.
function coverageGrid(grid) {
  const node = el("span", { class: "covgrid" });
  node.style.gridTemplateColumns = `repeat(${grid[0].length}, 9px)`;
  for (const row of grid) for (const n of row) node.append(el("span", n ? { class: "hit", title: `${n} samples` } : {}));
  return node;
}

// A small line of the camera's predicted sigma over the updates, the target dashed.
function sparkline(values, target) {
  const w = 80, h = 18, top = Math.max(target * 1.5, ...values);
  const svg = document.createElementNS(SVG, "svg");
  svg.setAttribute("width", w); svg.setAttribute("height", h); svg.setAttribute("class", "spark");
  const y = (v) => (h - 1 - (h - 2) * Math.min(v, top) / top).toFixed(1);
  const line = (points, color, dash) => {
    const p = document.createElementNS(SVG, "polyline");
    p.setAttribute("points", points); p.setAttribute("fill", "none"); p.setAttribute("stroke", color);
    if (dash) p.setAttribute("stroke-dasharray", "3 2");
    svg.append(p);
  };
  line(`0,${y(target)} ${w},${y(target)}`, "#7a8591", true);
  if (values.length > 1) line(values.map((v, i) => `${(w * i / (values.length - 1)).toFixed(1)},${y(v)}`).join(" "), "#1f6fb2");
  return svg;
}

// GET /captures/{id}/guidance of the live capture: the grids filling in, the sigmas falling, the advice.
function renderGuidance(captureId, g) {
  $("#live-guidance").hidden = false;
  $("#live-guidance").dataset.enough = g.enough;
  $("#live-guidance-frames").textContent = `${g.frames} wand frames` + (g.live ? " · updating" : "");
  $("#live-enough").hidden = !g.enough;
  $("#live-goal").textContent = `Enough when every camera's centre σ is below ${g.target.center_std_mm} mm and the wand has `
    + `covered ${Math.round(100 * g.target.coverage)}% of its image` + (g.solve.ok ? "." : ` (solve: ${g.solve.message})`);
  $("#live-advice").replaceChildren(...g.advice.map((a) => el("li", {}, a)));
  $("#live-cameras tbody").replaceChildren(...g.cameras.map((c) => {
    const key = `${captureId}/${c.id}`, history = sigmaHistory.get(key) || [];
    if (c.center_std_mm != null && history[history.length - 1] !== c.center_std_mm) history.push(c.center_std_mm);
    sigmaHistory.set(key, history.slice(-SIGMA_HISTORY));
    const sigma = c.center_std_mm == null ? el("td", {}, "–") : el("td", {},
      el("span", { class: c.center_std_mm < g.target.center_std_mm ? "sigma-ok" : "sigma-high" }, c.center_std_mm.toFixed(2)),
      sparkline(sigmaHistory.get(key), g.target.center_std_mm));
    return el("tr", { "data-guidance-camera": c.id, "data-coverage": c.coverage },
      el("td", {}, c.id), el("td", {}, coverageGrid(c.grid), ` ${Math.round(100 * c.coverage)}%`),
      el("td", {}, c.frames), sigma, el("td", {}, c.advice || "✓"));
  }));
}

async function pollGuidance(live) {
  // none while the L-frame is recorded or the rig waits for the wand: with no wand yet, every camera
  // would be "missing" the wand, which says nothing about the camera
  const wandPhase = live.phase === "wand" || ["done", "stopping"].includes(live.state);
  const show = live.capture_id && live.enough != null && wandPhase && !["idle", "failed"].includes(live.state);
  if (!show) { $("#live-guidance").hidden = true; return; }
  try { renderGuidance(live.capture_id, await api(`/captures/${live.capture_id}/guidance`)); }
  catch (err) { $("#live-goal").textContent = err.message; }
}

async function setAutostop(box) {
  try {
    await api("/capture", { method: "PATCH", headers: { "Content-Type": "application/json" },
      body: JSON.stringify({ stop_when_enough: box.checked }) });
  } catch (err) { alert(err.message); box.checked = !box.checked; }
  poll();
}

async function liveAction(button, path, question) {
  if (question && !confirm(question)) return;
  button.disabled = true;
  try { await api(path, { method: "POST" }); } catch (err) { alert(err.message); }
  button.disabled = false;
  poll();
}

async function pollWatch(live) {
  try {
    const doc = await api("/watch/live");
    const resolve = resolveWatch && doc.state !== "watching" ? await api(`/watch/${resolveWatch}`) : null;
    renderWatch(doc, live.state, shownJob, resolve);
  } catch (err) { $("#watch-error").hidden = false; $("#watch-error").textContent = err.message; }
}

async function watchAction(button, path, body) {
  button.disabled = true;
  try {
    const answer = await api(path, { method: "POST", headers: { "Content-Type": "application/json" },
      body: JSON.stringify(body) });
    if (path.endsWith("/resolve")) resolveWatch = answer.id;
  } catch (err) { alert(err.message); }
  button.disabled = false;
  poll();
}

async function showResult(jobId) {
  loadingJob = jobId;
  try {
    const job = await api(`/jobs/${jobId}`);
    if (!job.result) return;
    shownJob = jobId;
    const section = $("#result-section");
    section.hidden = false;
    section.dataset.jobId = jobId;
    $("#result-title").textContent = `job ${short(jobId)}, method ${job.method}`;
    $("#residuals").replaceChildren(...cameraTable(job.result));
    $("#judgement").replaceChildren(...rigJudgement(job.result));
    const offsets = offsetsTable(job.result);
    $("#offsets").replaceChildren(...offsets);
    $("#offsets").hidden = !offsets.length;
    $("#warnings").replaceChildren(...(job.result.warnings || []).map((w) => el("li", {}, w)));
    let samples = null;
    try { samples = await api(`/jobs/${jobId}/scene`); } catch (err) { $("#rig-note").textContent = `no wand samples: ${err.message}`; }
    if (shownJob !== jobId) return;  // another job was chosen meanwhile
    rigView = rigView || new RigView($("#rig-view"));
    rigView.show(job.result, samples);
    window.wandcalRig = rigView;  // the browser tests' handle on the projection and the labels
    const s = samples || { wand_frames: 0, points: [], volume: null };
    const said = [s.wand_frames ? `wand samples: ${s.wand_frames} frames (pale: first, dark: last)` : null,
      s.points.length ? `orange: ${s.points.length} single points` : null,
      s.volume ? "the box is the volume they fill" : null].filter(Boolean);
    $("#rig-note").textContent = said.join("; ");
    section.dataset.drawn = jobId;
  } catch (err) { $("#health").textContent = err.message; } finally {
    if (loadingJob === jobId) loadingJob = null;
  }
}

async function poll() {
  try {
    const health = await api("/health");
    $("#health").textContent = `${health.queue} queue · ${health.workers} worker(s) · ${health.jobs_running} running · ${health.jobs_queued} queued`;
    const [live, captures, jobs] = await Promise.all([api("/capture"), api("/captures"), api("/jobs")]);
    renderLive(live);
    await pollGuidance(live);
    await pollWatch(live);
    renderCaptures(captures.captures);
    renderJobs(jobs.jobs);
  } catch (err) {
    $("#health").textContent = err.message;
  }
}

$("#live-continue").addEventListener("click", (e) => liveAction(e.currentTarget, "/capture/continue"));
$("#live-stop").addEventListener("click", (e) => liveAction(e.currentTarget, "/capture/stop",
  "Stop the live capture? What was recorded so far is kept and stored."));
$("#watch-start").addEventListener("click", (e) => { resolveWatch = null; watchAction(e.currentTarget, "/watch/live", { job_id: shownJob }); });
$("#watch-resolve").addEventListener("click", (e) => watchAction(e.currentTarget, "/watch/live/resolve", {}));
$("#live-autostop").addEventListener("change", (e) => setAutostop(e.currentTarget));
$("#token").addEventListener("change", (e) => {
  token = e.target.value; localStorage.setItem("wandcal-token", token); setTokenCookie(); poll();
});
poll();
setInterval(poll, POLL_MS);
