// The rig page: polls the API once a second and draws what it finds. No external scripts.
"use strict";

const API = "/api/v1";
const POLL_MS = 1000;  // progress is written every 0.2 s; once a second is enough for people
const VIEW = { azimuth: -0.6, elevation: 0.45 };  // radians: a three-quarter view from above
let token = new URLSearchParams(location.hash.slice(1)).get("token") || localStorage.getItem("wandcal-token") || "";
let shownJob = null;

const $ = (sel) => document.querySelector(sel);
const el = (tag, attrs = {}, ...children) => {
  const node = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs)) {
    if (k === "class") node.className = v; else if (k.startsWith("data-")) node.setAttribute(k, v); else node[k] = v;
  }
  for (const c of children) node.append(c instanceof Node ? c : document.createTextNode(String(c)));
  return node;
};
const short = (id) => id.slice(0, 8);

async function api(path, options = {}) {
  const headers = Object.assign({}, options.headers || {});
  if (token) headers.Authorization = "Bearer " + token;
  const response = await fetch(API + path, Object.assign({}, options, { headers }));
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

function renderCaptures(captures) {
  const body = $("#captures tbody");
  body.replaceChildren(...captures.map((c) => {
    const run = el("button", { onclick: () => startJob(c.id) }, "calibrate");
    return el("tr", { "data-capture-id": c.id },
      el("td", { class: "id", title: c.id }, short(c.id)), el("td", {}, c.source + (c.name && c.name !== c.source ? ` (${c.name})` : "")),
      el("td", {}, c.frames), el("td", {}, ...coverage(c)), el("td", {}, run));
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
    const action = j.state === "done" ? el("button", { onclick: () => showResult(j.id) }, "show")
      : ["queued", "running"].includes(j.state) ? el("button", { onclick: () => cancelJob(j.id) }, "cancel") : "";
    return el("tr", { "data-job-id": j.id, "data-state": j.state },
      el("td", { class: "id", title: j.id }, short(j.id)), el("td", { class: "id" }, short(j.capture_id)),
      el("td", {}, j.method), el("td", { class: "state-" + j.state }, j.state), el("td", {}, progressText(j)),
      el("td", {}, j.attempts), el("td", {}, action));
  }));
  const latest = jobs.find((j) => j.state === "done");
  if (latest && shownJob === null) showResult(latest.id);
}

async function startJob(captureId) {
  try {
    await api("/jobs", { method: "POST", headers: { "Content-Type": "application/json" },
      body: JSON.stringify({ capture_id: captureId }) });  // the server's default method
    poll();
  } catch (err) { alert(err.message); }
}

async function cancelJob(jobId) {
  try { await api(`/jobs/${jobId}`, { method: "DELETE" }); poll(); } catch (err) { alert(err.message); }
}

// Orthographic view of world points (metres, z up) onto the canvas.
function projector(points, canvas) {
  const [ca, sa, ce, se] = [Math.cos(VIEW.azimuth), Math.sin(VIEW.azimuth), Math.cos(VIEW.elevation), Math.sin(VIEW.elevation)];
  const view = ([x, y, z]) => { const xr = ca * x - sa * y, yr = sa * x + ca * y; return [xr, ce * z - se * yr]; };
  const flat = points.map(view);
  const xs = flat.map((p) => p[0]), ys = flat.map((p) => p[1]);
  const [x0, x1, y0, y1] = [Math.min(...xs), Math.max(...xs), Math.min(...ys), Math.max(...ys)];
  const margin = 50, scale = Math.min((canvas.width - 2 * margin) / Math.max(x1 - x0, 1e-6), (canvas.height - 2 * margin) / Math.max(y1 - y0, 1e-6));
  return (p) => { const [u, v] = view(p); return [margin + (u - x0) * scale, canvas.height - margin - (v - y0) * scale]; };
}

function drawRig(result) {
  const canvas = $("#rig"), ctx = canvas.getContext("2d");
  const cams = result.cameras;
  const reach = Math.max(...cams.map((c) => Math.hypot(...c.center))) || 1;
  const axis = 0.25 * reach;  // viewing-direction arrows a quarter of the rig's size
  const dirs = cams.map((c) => c.R[2]);  // third row of world->camera R: the optical axis in the world
  const pts = [[0, 0, 0], ...cams.map((c) => c.center), ...cams.map((c, i) => c.center.map((v, k) => v + axis * dirs[i][k]))];
  const P = projector(pts, canvas);
  ctx.clearRect(0, 0, canvas.width, canvas.height);
  const line = (a, b, color, width = 1) => { ctx.strokeStyle = color; ctx.lineWidth = width; ctx.beginPath(); ctx.moveTo(...P(a)); ctx.lineTo(...P(b)); ctx.stroke(); };
  const unit = 0.2 * reach;
  line([0, 0, 0], [unit, 0, 0], "#c0392b", 2); line([0, 0, 0], [0, unit, 0], "#27ae60", 2); line([0, 0, 0], [0, 0, unit], "#2c6fbb", 2);
  ctx.font = "12px system-ui, sans-serif";
  cams.forEach((c, i) => {
    const tip = c.center.map((v, k) => v + axis * dirs[i][k]);
    line(c.center, tip, "#7a8591", 1.5);
    const [u, v] = P(c.center);
    ctx.fillStyle = "#1d2630"; ctx.beginPath(); ctx.arc(u, v, 5, 0, 2 * Math.PI); ctx.fill();
    const rms = c.reprojection_rms_px != null ? ` ${c.reprojection_rms_px.toFixed(2)} px` : "";
    ctx.fillText(c.id + rms, u + 8, v - 8);
  });
}

async function showResult(jobId) {
  try {
    const job = await api(`/jobs/${jobId}`);
    if (!job.result) return;
    shownJob = jobId;
    $("#result-section").hidden = false;
    $("#result-title").textContent = `job ${short(jobId)}, method ${job.method}`;
    drawRig(job.result);
    $("#residuals tbody").replaceChildren(...job.result.cameras.map((c) => el("tr", { "data-camera": c.id },
      el("td", {}, c.id), el("td", {}, c.center.map((v) => v.toFixed(3)).join(", ")),
      el("td", {}, c.reprojection_rms_px != null ? c.reprojection_rms_px.toFixed(3) : "–"),
      el("td", {}, c.observations != null ? c.observations : "–"))));
    $("#warnings").replaceChildren(...(job.result.warnings || []).map((w) => el("li", {}, w)));
  } catch (err) { $("#health").textContent = err.message; }
}

async function poll() {
  try {
    const health = await api("/health");
    $("#health").textContent = `${health.queue} queue · ${health.workers} worker(s) · ${health.jobs_running} running · ${health.jobs_queued} queued`;
    const [captures, jobs] = await Promise.all([api("/captures"), api("/jobs")]);
    renderCaptures(captures.captures);
    renderJobs(jobs.jobs);
  } catch (err) {
    $("#health").textContent = err.message;
  }
}

$("#token").addEventListener("change", (e) => { token = e.target.value; localStorage.setItem("wandcal-token", token); poll(); });
poll();
setInterval(poll, POLL_MS);
