// The rig in 3D, as Motive, QTM and Vicon show it: cameras as frusta with their labels, the wand's
// samples and the volume they fill, the world axes and a floor grid. Drag turns the view, the
// wheel zooms, shift-drag (or the right button) pans, a double click goes back to the first view.
// three.js is vendored (static/vendor/README.md): the page needs no network.
import * as THREE from "./vendor/three.module.min.js";
import { placeLabels } from "./labels.js";

// matplotlib's tab10, the report's camera colours (service/report/figures.py): a camera has one colour everywhere
const CAMERA_COLOURS = ["#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2", "#7f7f7f",
  "#bcbd22", "#17becf"];
const AXIS_COLOURS = ["#c0392b", "#27ae60", "#2c6fbb"];  // x, y, z: red, green, blue as in every 3D tool
const FRUSTUM_DEPTH = 0.12;  // of the scene's extent, as in the report: shows where a camera looks without clutter
const AXIS_LENGTH = 0.15;  // of the scene's extent: the world axes at the origin
const UP_TAB = 0.3;  // of the image height: the filled tab on a frustum's top edge, which way its image is up
const HOME = { azimuth: -2.2, elevation: 0.5 };  // radians: a three-quarter view from above, as the report's 3D panel
const FOV_DEG = 35;  // a long lens: the rig's proportions barely distorted, still a sense of depth
const FIT_MARGIN = 0.8;  // of the bounding sphere, which is loose around a flat rig: the first view fills the canvas
const TURN_PER_PX = 0.008;  // radians per dragged pixel: a drag across the view turns it about once
const ZOOM_PER_DELTA = 0.0015;  // a wheel notch (deltaY 100) zooms by 16%
const MAX_ELEVATION = 1.55;  // radians, just short of straight down/up, where the orbit's "up" degenerates
const SAMPLE_PX = 3;  // the wand samples' size on screen, pixels
const TRAIL_EARLY = new THREE.Color("#9ecae1");  // the trail's first frames pale, its last dark: where the wand went
const TRAIL_LATE = new THREE.Color("#08306b");
const POINT_COLOUR = "#e67e22";  // single-point tracks, orange as in the report
const AXIS_POINT_COLOUR = "#8e44ad";
const GRID_LINES = 10;  // about this many grid lines across the scene, at a round spacing
// who gets the free spot first when labels crowd: the cameras, then the world's origin and axes
const PRIORITY = { camera: 0, origin: 1, axis: 2, "axis-point": 3, volume: 4 };

// (3x3 as rows) world -> drawing coordinates, z up. A world in the first camera's frame (y down
// its image, z along its view) is drawn with -y up, as the report draws it (display_axes).
const drawingMatrix = (frame) => frame === "camera" ? [[1, 0, 0], [0, 0, 1], [0, -1, 0]] : [[1, 0, 0], [0, 1, 0], [0, 0, 1]];
const mul = (M, p) => M.map((row) => row[0] * p[0] + row[1] * p[1] + row[2] * p[2]);
const v3 = (p) => new THREE.Vector3(p[0], p[1], p[2]);

function roundStep(span) {
  const raw = span / GRID_LINES, p = 10 ** Math.floor(Math.log10(raw));
  return [1, 2, 5, 10].map((m) => m * p).find((s) => s >= raw);
}

function lines(segments, colour, opacity = 1) {
  const geometry = new THREE.BufferGeometry();
  geometry.setAttribute("position", new THREE.Float32BufferAttribute(segments.flat(2), 3));
  return new THREE.LineSegments(geometry, new THREE.LineBasicMaterial({ color: colour, transparent: opacity < 1, opacity }));
}

function cloud(points, colours, size) {
  const geometry = new THREE.BufferGeometry();
  geometry.setAttribute("position", new THREE.Float32BufferAttribute(points.flat(), 3));
  geometry.setAttribute("color", new THREE.Float32BufferAttribute(colours.flat(), 3));
  return new THREE.Points(geometry, new THREE.PointsMaterial({ size, sizeAttenuation: false, vertexColors: true }));
}

// (5, 3) a camera's centre and its image corners (top-left, top-right, bottom-right, bottom-left)
// at `depth` along its view, world; and the tip of the "up" tab above the top edge.
function frustum(cam, depth) {
  const K = cam.K, [w, h] = [cam.width, cam.height];
  const ray = ([u, v]) => [(u - K[0][2]) / K[0][0] * depth, (v - K[1][2]) / K[1][1] * depth, depth];
  const toWorld = (x) => [0, 1, 2].map((k) => cam.R[0][k] * x[0] + cam.R[1][k] * x[1] + cam.R[2][k] * x[2] + cam.center[k]);
  const corners = [[0, 0], [w, 0], [w, h], [0, h]].map((uv) => toWorld(ray(uv)));
  return { apex: cam.center, corners, tab: toWorld(ray([w / 2, -UP_TAB * h])) };
}

export class RigView {
  constructor(container) {
    this.container = container;
    this.labelLayer = Object.assign(document.createElement("div"), { className: "rig-labels" });
    this.leaders = document.createElementNS("http://www.w3.org/2000/svg", "svg");
    this.leaders.setAttribute("class", "rig-leaders");
    try {
      this.renderer = new THREE.WebGLRenderer({ antialias: true });
    } catch (err) {
      container.append(Object.assign(document.createElement("p"), { className: "error",
        textContent: `The 3D view needs WebGL, which this browser does not offer (${err.message}).` }));
      return;
    }
    this.renderer.setPixelRatio(window.devicePixelRatio || 1);
    this.renderer.setClearColor(0xffffff);
    this.canvas = this.renderer.domElement;
    this.canvas.id = "rig";
    this.canvas.setAttribute("aria-label", "the rig in 3D: drag to turn, wheel to zoom, shift-drag to pan, double-click to reset");
    container.append(this.canvas, this.leaders, this.labelLayer);
    this.camera = new THREE.PerspectiveCamera(FOV_DEG, 1, 0.01, 1000);
    this.camera.up.set(0, 0, 1);
    this.orbit = { ...HOME, distance: 1, target: new THREE.Vector3() };
    this.labels = [];
    this.bindMouse();
    new ResizeObserver(() => this.resize()).observe(container);
  }

  get ok() { return !!this.renderer; }

  // Build the scene of a wandcal-result/1 document and its wandcal-scene/1 samples (or null).
  show(result, samples) {
    if (!this.ok) return;
    const M = drawingMatrix((result.world || {}).frame);
    const D = (p) => v3(mul(M, p));
    const cams = result.cameras;
    const s = samples || { wand: [], points: [], axis: {}, static_markers: [], volume: null };
    const all = [[0, 0, 0], ...cams.map((c) => c.center), ...s.wand, ...s.points].map((p) => mul(M, p));
    const box = new THREE.Box3().setFromPoints(all.map(v3));
    const extent = Math.max(box.getSize(new THREE.Vector3()).length(), 1e-3);
    const unit = (result.world || {}).scale === "arbitrary" ? "units" : "m";
    const scene = new THREE.Scene();
    const labels = [];

    // the floor: a grid at z = 0 (the static object or axis points stand on it), else under everything
    const onFloor = ["static_object", "axis"].includes((result.world || {}).frame);
    const step = roundStep(Math.max(box.max.x - box.min.x, box.max.y - box.min.y, 1e-3));
    const z0 = onFloor ? 0 : box.min.z;
    const [x0, x1] = [Math.floor(box.min.x / step) * step, Math.ceil(box.max.x / step) * step];
    const [y0, y1] = [Math.floor(box.min.y / step) * step, Math.ceil(box.max.y / step) * step];
    const grid = [];
    for (let x = x0; x <= x1 + step / 2; x += step) grid.push([[x, y0, z0], [x, y1, z0]]);
    for (let y = y0; y <= y1 + step / 2; y += step) grid.push([[x0, y, z0], [x1, y, z0]]);
    scene.add(lines(grid, "#b8c0c8", 0.7));

    const axisLength = AXIS_LENGTH * extent;
    ["x", "y", "z"].forEach((name, k) => {
      const dir = D([0, 1, 2].map((j) => (j === k ? 1 : 0)));
      scene.add(new THREE.ArrowHelper(dir, new THREE.Vector3(), axisLength, AXIS_COLOURS[k], 0.2 * axisLength, 0.1 * axisLength));
      labels.push({ text: name, at: dir.clone().multiplyScalar(1.12 * axisLength), kind: "axis", colour: AXIS_COLOURS[k] });
    });
    labels.push({ text: "origin", at: new THREE.Vector3(), kind: "origin" });

    if (s.wand.length) {
      const n = s.wand.length;
      const colours = s.wand.map((_, i) => TRAIL_EARLY.clone().lerp(TRAIL_LATE, n > 1 ? i / (n - 1) : 1).toArray());
      scene.add(cloud(s.wand.map((p) => mul(M, p)), colours, SAMPLE_PX));
    }
    if (s.points.length) {
      const c = new THREE.Color(POINT_COLOUR).toArray();
      scene.add(cloud(s.points.map((p) => mul(M, p)), s.points.map(() => c), SAMPLE_PX));
    }
    if (s.static_markers.length) scene.add(cloud(s.static_markers.map((p) => mul(M, p)), s.static_markers.map(() => [0, 0, 0]), 7));
    for (const [role, p] of Object.entries(s.axis)) {
      scene.add(cloud([mul(M, p)], [new THREE.Color(AXIS_POINT_COLOUR).toArray()], 8));
      if (role !== "origin") labels.push({ text: role, at: D(p), kind: "axis-point", colour: AXIS_POINT_COLOUR });
    }
    if (s.volume) {
      const [lo, hi] = [D(s.volume.min), D(s.volume.max)];
      const vbox = new THREE.Box3(lo.clone().min(hi), lo.clone().max(hi));
      const size = vbox.getSize(new THREE.Vector3()), centre = vbox.getCenter(new THREE.Vector3());
      const solid = new THREE.Mesh(new THREE.BoxGeometry(size.x, size.y, size.z),
        new THREE.MeshBasicMaterial({ color: "#2c6fbb", transparent: true, opacity: 0.06, depthWrite: false }));
      solid.position.copy(centre);
      const edges = new THREE.LineSegments(new THREE.EdgesGeometry(solid.geometry), new THREE.LineBasicMaterial({ color: "#2c6fbb", transparent: true, opacity: 0.55 }));
      edges.position.copy(centre);
      scene.add(solid, edges);
      const dims = [0, 1, 2].map((k) => (s.volume.max[k] - s.volume.min[k]).toFixed(2)).join(" × ");
      labels.push({ text: `volume ${dims} ${unit}`, at: new THREE.Vector3(vbox.max.x, vbox.max.y, vbox.max.z), kind: "volume" });
    }

    const depth = FRUSTUM_DEPTH * extent;
    cams.forEach((cam, i) => {
      const colour = CAMERA_COLOURS[i % CAMERA_COLOURS.length];
      const f = frustum(cam, depth);
      const [a, c] = [mul(M, f.apex), f.corners.map((p) => mul(M, p))];
      scene.add(lines([...c.map((q) => [a, q]), ...c.map((q, k) => [q, c[(k + 1) % 4]])], colour));
      const tab = new THREE.BufferGeometry();
      tab.setAttribute("position", new THREE.Float32BufferAttribute([...c[0], ...c[1], ...mul(M, f.tab)], 3));
      scene.add(new THREE.Mesh(tab, new THREE.MeshBasicMaterial({ color: colour, side: THREE.DoubleSide })));
      const dot = new THREE.Mesh(new THREE.SphereGeometry(0.012 * extent, 12, 8), new THREE.MeshBasicMaterial({ color: colour }));
      dot.position.copy(v3(a));
      scene.add(dot);
      const rms = cam.reprojection_rms_px != null ? ` ${cam.reprojection_rms_px.toFixed(2)} px` : "";
      labels.push({ text: cam.id + rms, at: v3(a), kind: "camera", colour, camera: cam.id });
    });

    if (this.scene) this.scene.traverse((o) => { if (o.geometry) o.geometry.dispose(); if (o.material) o.material.dispose(); });
    this.scene = scene;
    this.M = M;
    this.extent = extent;
    // far enough that the scene's bounding sphere fits the (vertical) field of view, with a margin
    const fit = (FIT_MARGIN * extent) / 2 / Math.sin((FOV_DEG * Math.PI) / 360);
    this.home = { ...HOME, distance: fit, target: box.getCenter(new THREE.Vector3()) };
    this.setLabels(labels);
    this.reset();
  }

  setLabels(labels) {
    this.labelLayer.replaceChildren();
    this.labels = labels.map((l) => {
      const node = Object.assign(document.createElement("span"), { className: `rig-label rig-label-${l.kind}`, textContent: l.text });
      if (l.kind === "camera") node.style.borderColor = l.colour;
      if (l.kind === "axis" || l.kind === "axis-point") node.style.color = l.colour;
      if (l.camera) node.dataset.camera = l.camera;
      this.labelLayer.append(node);
      return { ...l, node };
    });
  }

  reset() {
    if (!this.home) return;
    this.orbit = { ...this.home, target: this.home.target.clone() };
    this.resize();
  }

  resize() {
    if (!this.ok || !this.scene) return;
    const width = Math.max(320, this.container.clientWidth), height = Math.round(0.62 * width);
    this.renderer.setSize(width, height);
    this.camera.aspect = width / height;
    this.camera.updateProjectionMatrix();
    this.leaders.setAttribute("width", width);
    this.leaders.setAttribute("height", height);
    this.render();
  }

  render() {
    const o = this.orbit, ce = Math.cos(o.elevation);
    this.camera.position.copy(o.target).add(new THREE.Vector3(ce * Math.cos(o.azimuth), ce * Math.sin(o.azimuth), Math.sin(o.elevation)).multiplyScalar(o.distance));
    this.camera.near = o.distance / 1000;
    this.camera.far = o.distance * 100;
    this.camera.updateProjectionMatrix();
    this.camera.lookAt(o.target);
    this.camera.updateMatrixWorld();
    this.renderer.render(this.scene, this.camera);
    this.layoutLabels();
  }

  // Screen position (CSS pixels from the canvas's top-left) of a drawing-space point, or null behind the eye.
  screen(p) {
    const q = p.clone().project(this.camera);
    if (q.z > 1) return null;
    const { width, height } = this.canvas.getBoundingClientRect();
    return [(q.x + 1) / 2 * width, (1 - q.y) / 2 * height];
  }

  // Screen position of a world point (metres): the tests' handle on the projection.
  project(world) { return this.screen(v3(mul(this.M, world))); }

  layoutLabels() {
    const { width, height } = this.canvas.getBoundingClientRect();
    const items = this.labels.map((l) => ({ l, anchor: this.screen(l.at), w: l.node.offsetWidth, h: l.node.offsetHeight }));
    const shown = items.filter((it) => it.anchor && it.w > 0);
    const boxes = placeLabels(shown.map((it) => ({ anchor: it.anchor, width: it.w, height: it.h, priority: PRIORITY[it.l.kind] })), width, height);
    this.leaders.replaceChildren();
    for (const it of items) it.l.node.hidden = !shown.includes(it);
    shown.forEach((it, k) => {
      const b = boxes[k];
      Object.assign(it.l.node.style, { left: `${b.left}px`, top: `${b.top}px` });
      if (b.leader) {
        const line = document.createElementNS("http://www.w3.org/2000/svg", "line");
        const [ex, ey] = b.leader;
        for (const [k2, v] of Object.entries({ x1: it.anchor[0], y1: it.anchor[1], x2: ex, y2: ey })) line.setAttribute(k2, v.toFixed(1));
        line.setAttribute("stroke", it.l.colour || "#7a8591");
        this.leaders.append(line);
      }
    });
  }

  bindMouse() {
    let drag = null;
    this.canvas.addEventListener("contextmenu", (e) => e.preventDefault());
    this.canvas.addEventListener("pointerdown", (e) => {
      drag = { x: e.clientX, y: e.clientY, pan: e.shiftKey || e.button === 2 };
      this.canvas.setPointerCapture(e.pointerId);
    });
    this.canvas.addEventListener("pointermove", (e) => {
      if (!drag) return;
      const [dx, dy] = [e.clientX - drag.x, e.clientY - drag.y];
      [drag.x, drag.y] = [e.clientX, e.clientY];
      const o = this.orbit;
      if (drag.pan) {
        const perPx = (2 * o.distance * Math.tan((FOV_DEG * Math.PI) / 360)) / this.canvas.clientHeight;
        const right = new THREE.Vector3().setFromMatrixColumn(this.camera.matrixWorld, 0);
        const up = new THREE.Vector3().setFromMatrixColumn(this.camera.matrixWorld, 1);
        o.target.add(right.multiplyScalar(-dx * perPx)).add(up.multiplyScalar(dy * perPx));
      } else {
        o.azimuth -= dx * TURN_PER_PX;
        o.elevation = Math.max(-MAX_ELEVATION, Math.min(MAX_ELEVATION, o.elevation + dy * TURN_PER_PX));
      }
      this.render();
    });
    const end = () => { drag = null; };
    this.canvas.addEventListener("pointerup", end);
    this.canvas.addEventListener("pointercancel", end);
    this.canvas.addEventListener("wheel", (e) => {
      e.preventDefault();
      this.orbit.distance *= Math.exp(e.deltaY * ZOOM_PER_DELTA);
      this.render();
    }, { passive: false });
    this.canvas.addEventListener("dblclick", () => this.reset());
  }
}
