// Label placement for the 3D view: every label inside the canvas, none over another, none over
// another label's anchor (a camera's dot); a label pushed away from its anchor gets a leader line.
// Greedy, in the order of `priority` (lower first): the first candidate spot that is free wins.

const GAP_PX = 5;  // between a label and its anchor: close enough to read as one
const MARGIN_PX = 2;  // kept from the canvas's edge
const ANCHOR_PX = 5;  // half the size of the square around each anchor that no other label may cover
const RING_STEP_PX = 8;  // candidate spots lie on rings around the anchor, this far apart
const RING_ANGLES = 16;  // candidate spots per ring
const LEADER_PX = 12;  // a label whose nearest edge is farther than this from its anchor gets a leader line

const overlap = (a, b) => Math.max(0, Math.min(a.right, b.right) - Math.max(a.left, b.left))
  * Math.max(0, Math.min(a.bottom, b.bottom) - Math.max(a.top, b.top));
const boxAt = (left, top, w, h) => ({ left, top, right: left + w, bottom: top + h });

function* candidates([x, y], w, h, reach) {
  // beside the anchor first, as a label is usually written: right and up, right and down, left, above, below
  yield [x + GAP_PX, y - GAP_PX - h];
  yield [x + GAP_PX, y + GAP_PX];
  yield [x - GAP_PX - w, y - GAP_PX - h];
  yield [x - GAP_PX - w, y + GAP_PX];
  yield [x - w / 2, y - GAP_PX - h];
  yield [x - w / 2, y + GAP_PX];
  for (let r = RING_STEP_PX; r <= reach; r += RING_STEP_PX) {
    for (let k = 0; k < RING_ANGLES; k++) {
      const a = (2 * Math.PI * k) / RING_ANGLES;
      // the box's centre on a ring that clears the anchor by r
      const cx = x + Math.cos(a) * (r + w / 2), cy = y - Math.sin(a) * (r + h / 2);
      yield [cx - w / 2, cy - h / 2];
    }
  }
}

// items: [{anchor: [x, y], width, height, priority}] in CSS pixels of a width x height canvas.
// Returns per item (input order) {left, top, right, bottom, leader: [x, y] | null}.
export function placeLabels(items, width, height) {
  const order = items.map((_, i) => i).sort((i, j) => (items[i].priority || 0) - (items[j].priority || 0) || i - j);
  const anchorBoxes = items.map(({ anchor: [x, y] }) => boxAt(x - ANCHOR_PX, y - ANCHOR_PX, 2 * ANCHOR_PX, 2 * ANCHOR_PX));
  const placed = [], out = new Array(items.length);
  const reach = Math.max(width, height);
  for (const i of order) {
    const { anchor, width: w, height: h } = items[i];
    const clamp = ([l, t]) => boxAt(Math.min(Math.max(l, MARGIN_PX), width - MARGIN_PX - w),
      Math.min(Math.max(t, MARGIN_PX), height - MARGIN_PX - h), w, h);
    let best = null, bestCost = Infinity;
    for (const spot of candidates(anchor, w, h, reach)) {
      const box = clamp(spot);
      const cost = placed.reduce((s, b) => s + overlap(box, b), 0) * 1000
        + anchorBoxes.reduce((s, b, k) => s + (k === i ? 0 : overlap(box, b)), 0);
      if (cost < bestCost) [best, bestCost] = [box, cost];
      if (cost === 0) break;
    }
    placed.push(best);
    const nx = Math.min(Math.max(anchor[0], best.left), best.right), ny = Math.min(Math.max(anchor[1], best.top), best.bottom);
    out[i] = { ...best, leader: Math.hypot(nx - anchor[0], ny - anchor[1]) > LEADER_PX ? [nx, ny] : null };
  }
  return out;
}
