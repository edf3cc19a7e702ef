// The Check panel: one capture judged against the result the Rig panel shows (POST
// /captures/{id}/check, what `wandcal check RESULT CAPTURE` prints), and, when a camera moved, the
// re-solve of only the moved cameras from that result (a job with from_job and solve_only, what
// `wandcal calibrate CAPTURE --from RESULT --solve-only CAM` runs).
import { el } from "./dom.js";

const VERDICT_WORDS = {
  agrees: "every camera agrees with the result",
  moved: "a camera moved",
  unjudged: "some cameras could not be judged",
  rebuilt: "another rig, or a rebuilt one: calibrate afresh",
};
const VERDICT_CLASS = { agrees: "verdict-good", moved: "verdict-poor", unjudged: "verdict-poor", rebuilt: "verdict-poor" };

const px = (v) => (typeof v === "number" ? v.toFixed(3) : "–");

function cameraRow(c) {
  const state = c.moved === true ? "moved" : c.moved === false ? "agrees" : "not judged";
  const placed = c.turned_deg != null ? `${c.turned_deg.toFixed(3)}°, ${(1000 * c.shifted_m).toFixed(1)} mm` : "";
  return el("tr", { "data-camera": c.id, "data-status": state },
    el("td", {}, c.id), el("td", { class: c.moved ? "verdict-poor" : "" }, state), el("td", {}, px(c.rms_px)),
    el("td", {}, px(c.median_px)), el("td", {}, c.frames), el("td", {}, placed), el("td", {}, c.reason));
}

// answer: CheckPublic; onResolve(moved ids): starts the re-solve job. Returns the panel's children.
export function checkPanel(answer, jobLabel, onResolve) {
  const head = el("p", { "data-verdict": answer.verdict },
    `capture ${answer.capture_id.slice(0, 8)} against ${jobLabel}: `,
    el("strong", { class: VERDICT_CLASS[answer.verdict] || "" }, VERDICT_WORDS[answer.verdict] || answer.verdict),
    ` (wandcal check exits ${answer.exit_code})`);
  const table = el("table", { id: "check-cameras" },
    el("thead", {}, el("tr", {}, ...["camera", "state", "RMS (px)", "median (px)", "frames", "placed again: turn, shift",
      "why"].map((h) => el("th", {}, h)))),
    el("tbody", {}, ...answer.cameras.map(cameraRow)));
  const parts = [head, table, el("p", { class: "muted", id: "check-advice" }, answer.advice)];
  if (answer.moved.length) {
    const names = answer.moved.join(", ");
    const button = el("button", { class: "primary", id: "check-resolve" }, `Re-solve ${names} from this result`);
    button.onclick = () => { button.disabled = true; onResolve(answer.moved); };
    parts.push(el("p", {}, button, el("span", { class: "muted" },
      ` only ${names} placed again from this capture; every other camera held where the result has it`)));
  }
  return parts;
}
