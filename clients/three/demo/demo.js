// The demo page's script (index.html): builds the scene, lets VemlightLights light it, and exposes
// `window.vemlightDemo` — its state, a pixel measurement and a frame-rate count — for the browser
// test (tests/demo_browser.rs) and for anyone curious in the console.

import * as THREE from "three";
import { VemlightLights, luminance } from "vemlight-three";

const $ = (id) => document.getElementById(id);
const params = new URLSearchParams(location.search);
const errors = [];
window.addEventListener("error", (e) => errors.push(String(e.message || e)));
window.addEventListener("unhandledrejection", (e) => errors.push(String(e.reason)));
const consoleError = console.error.bind(console);
console.error = (...args) => {
  errors.push(args.map(String).join(" "));
  consoleError(...args);
};

const token = params.get("access_token");
if (token) $("live").search = `?access_token=${encodeURIComponent(token)}`;
const budget = {
  lights: Number(params.get("lights") ?? 16),
  shadowed: Number(params.get("shadowed") ?? 4),
  maxError: params.get("max_error") ? Number(params.get("max_error")) : null,
};
const tonemap = params.get("tonemap") === "linear" ? "linear" : "aces";
for (const [id, v] of [["lights", budget.lights], ["shadowed", budget.shadowed], ["max_error", budget.maxError ?? ""]]) {
  const sel = $(id);
  if (![...sel.options].some((o) => o.value === String(v))) sel.add(new Option(String(v)));
  sel.value = String(v);
}

// The scene: +Y up, the camera south-east of the objects looking north (−Z), as DESIGN.md's frame.
const renderer = new THREE.WebGLRenderer({ canvas: $("view"), antialias: params.get("aa") !== "0" });
renderer.setPixelRatio(Math.min(2, window.devicePixelRatio || 1));
renderer.shadowMap.enabled = true;
renderer.shadowMap.type = THREE.PCFShadowMap;
// Linear: display = exposure × radiance (clamped), so the test can read radiance back from pixels.
renderer.toneMapping = tonemap === "linear" ? THREE.LinearToneMapping : THREE.ACESFilmicToneMapping;
const scene = new THREE.Scene();
scene.background = new THREE.Color(0x1c2330);
const camera = new THREE.PerspectiveCamera(45, 1, 0.1, 100);
camera.position.set(0, 6.5, 9.5);
camera.lookAt(0, 0.3, -0.8);

const lambert = (r, g, b) => new THREE.MeshLambertMaterial({ color: new THREE.Color().setRGB(r, g, b, THREE.LinearSRGBColorSpace) });
const GROUND_ALBEDO = 0.5;
const ground = new THREE.Mesh(new THREE.PlaneGeometry(30, 30), lambert(GROUND_ALBEDO, GROUND_ALBEDO, GROUND_ALBEDO));
ground.rotation.x = -Math.PI / 2;
ground.receiveShadow = true;
ground.name = "ground";
scene.add(ground);
const objects = [
  ["box", new THREE.BoxGeometry(1.2, 1.6, 1.2), [-1.8, 0.8, 0.6], lambert(0.6, 0.25, 0.2)],
  ["sphere", new THREE.SphereGeometry(0.7, 48, 24), [1.6, 0.7, 1.2], lambert(0.2, 0.35, 0.6)],
  ["pole", new THREE.CylinderGeometry(0.22, 0.22, 2.4, 32), [0.3, 1.2, -1.2], lambert(0.7, 0.7, 0.7)],
  ["knot", new THREE.TorusKnotGeometry(0.45, 0.15, 128, 16), [2.8, 1.1, -2.4], lambert(0.3, 0.6, 0.3)],
].map(([name, geometry, at, material]) => {
  const m = new THREE.Mesh(geometry, material);
  m.name = name;
  m.position.set(...at);
  m.castShadow = m.receiveShadow = true;
  scene.add(m);
  return m;
});

// The shadow cameras cover the objects and the ground around them that they can shadow.
const target = new THREE.Box3(new THREE.Vector3(-7, 0, -7), new THREE.Vector3(7, 2.6, 6));
const client = new VemlightLights(scene, {
  url: "/v1/stream",
  token,
  target,
  mapSize: Number(params.get("map") ?? 1024),
  occluderDistance: 0.8,
  ...budget,
});

function onBudget() {
  budget.lights = Number($("lights").value);
  budget.shadowed = Number($("shadowed").value);
  budget.maxError = $("max_error").value ? Number($("max_error").value) : null;
  const q = new URLSearchParams(location.search);
  q.set("lights", budget.lights);
  q.set("shadowed", budget.shadowed);
  if (budget.maxError == null) q.delete("max_error");
  else q.set("max_error", budget.maxError);
  history.replaceState(null, "", `?${q}`);
  client.setBudget(budget);
}
for (const id of ["lights", "shadowed", "max_error"]) $(id).onchange = onBudget;

function resize() {
  const w = window.innerWidth, h = window.innerHeight;
  renderer.setSize(w, h, false);
  camera.aspect = w / h;
  camera.updateProjectionMatrix();
}
window.addEventListener("resize", resize);
resize();

// Exposure follows the light: open ground (n = +Y) sits at display value 0.5 (linear) or about
// mid-grey (ACES), from the lights as currently drawn.
const _up = new THREE.Vector3(0, 1, 0), _e = new THREE.Vector3(), _d = new THREE.Vector3();
function groundIrradiance() {
  let e = luminance(client.probe.sh.getIrradianceAt(_up, _e).toArray());
  for (const { light } of client.shadowedLights) {
    _d.copy(light.position).sub(light.target.position).normalize();
    e += Math.max(0, _d.y) * light.intensity * luminance(light.color.toArray());
  }
  return e;
}

const frameTimes = [];
let frames = 0, last = performance.now(), pending = [];
renderer.setAnimationLoop((now) => {
  const dt = Math.min(0.25, (now - last) / 1000);
  last = now;
  // A measurement asked with `snap` is taken of lights drawn exactly where the last set puts
  // them: the smoothing is completed in this frame (it goes on from there in the next).
  client.update(pending.some((p) => p.options?.snap) ? Infinity : dt);
  const radiance = (GROUND_ALBEDO / Math.PI) * groundIrradiance();
  if (radiance > 0) renderer.toneMappingExposure = (tonemap === "linear" ? 0.5 : 0.8) / radiance;
  renderer.render(scene, camera);
  frames++;
  frameTimes.push(now);
  while (frameTimes.length && frameTimes[0] < now - 2000) frameTimes.shift();
  // Measurements read the drawing buffer right after the render, before it is presented.
  for (const p of pending.splice(0)) {
    try {
      p.resolve(measureNow(p.options));
    } catch (err) {
      p.reject(err);
    }
  }
  if (frames % 15 === 0) showStatus();
});

function fps() {
  if (frameTimes.length < 2) return 0;
  return ((frameTimes.length - 1) * 1000) / (frameTimes[frameTimes.length - 1] - frameTimes[0]);
}

function showStatus() {
  const s = client.stats;
  const ids = client.shadowedLights.map(({ id, light }) => {
    _d.copy(light.position).sub(light.target.position).normalize();
    return `#${id} (el ${THREE.MathUtils.radToDeg(Math.asin(_d.y)).toFixed(0)}°)`;
  });
  $("status").textContent =
    `${s.connected ? "connected" : "not connected"} · seq ${s.seq ?? "–"} · ` +
    `${client.lastSet?.lights.length ?? 0} lights, ${ids.length} shadowed (${s.wire})\n` +
    `shadowed: ${ids.join(", ") || "none"}\n` +
    `${fps().toFixed(1)} frames/s · dropped ${s.droppedOld} old, ${s.droppedOutOfOrder} out of order`;
}

// ---- measurement (window.vemlightDemo.measure) ----

const raycaster = new THREE.Raycaster();

function toLinear(c) {
  const v = c / 255;
  return v <= 0.04045 ? v / 12.92 : ((v + 0.055) / 1.055) ** 2.4;
}

// The drawing buffer, read once per measurement right after the render (before it is presented).
function readFrame() {
  const gl = renderer.getContext();
  const w = gl.drawingBufferWidth, h = gl.drawingBufferHeight;
  const data = new Uint8Array(4 * w * h);
  gl.readPixels(0, 0, w, h, gl.RGBA, gl.UNSIGNED_BYTE, data);
  return { w, h, data };
}

// Mean scene radiance (luminance) in a (2r+1)² pixel window around world point p: sRGB decoded,
// exposure divided out (meaningful with tonemap=linear).
function radianceAt(frame, p, r = 3) {
  const { w, h, data } = frame;
  const ndc = p.clone().project(camera);
  const px = Math.round(((ndc.x + 1) / 2) * w), py = Math.round(((ndc.y + 1) / 2) * h);
  const onScreen = ndc.z < 1 && px >= r + 4 && py >= r + 4 && px < w - r - 4 && py < h - r - 4;
  if (!onScreen) return { onScreen, pixel: [px, h - py] };
  let sum = 0, max = 0, n = 0;
  for (let y = py - r; y <= py + r; y++) {
    for (let x = px - r; x <= px + r; x++) {
      const i = 4 * (y * w + x);
      sum += luminance([toLinear(data[i]), toLinear(data[i + 1]), toLinear(data[i + 2])]);
      max = Math.max(max, data[i], data[i + 1], data[i + 2]);
      n++;
    }
  }
  return { onScreen, pixel: [px, h - py], radiance: sum / n / renderer.toneMappingExposure, clipped: max >= 255 };
}

// Whether the camera sees ground point p (no object in front of it).
function cameraSees(p) {
  const dir = p.clone().sub(camera.position);
  const dist = dir.length();
  raycaster.set(camera.position, dir.normalize());
  raycaster.far = dist - 0.01;
  return raycaster.intersectObjects(objects, false).length === 0;
}

// Fraction of a light's disc (angular radius `a` about `dir`) seen from p past the objects (the
// ground casts no shadow: a light below the horizon does not light the ground anyway).
function visibility(p, dir, a) {
  const d = new THREE.Vector3(...dir).normalize();
  const t1 = new THREE.Vector3().crossVectors(d, Math.abs(d.y) < 0.9 ? _up : new THREE.Vector3(1, 0, 0)).normalize();
  const t2 = new THREE.Vector3().crossVectors(d, t1);
  const rays = [[0, 0]];
  // A light of small extent (the sun: 0.0046 rad) is one ray; a wider one a disc of 13.
  for (let k = 0; k < (a < 0.01 ? 0 : 12); k++) {
    const phi = (k * 2 * Math.PI) / 12, s = k % 2 ? 0.45 : 0.85;
    rays.push([s * Math.cos(phi), s * Math.sin(phi)]);
  }
  const t = Math.tan(Math.min(a, 1.2));
  let seen = 0;
  for (const [u, v] of rays) {
    const ray = d.clone().addScaledVector(t1, u * t).addScaledVector(t2, v * t).normalize();
    raycaster.set(p, ray);
    raycaster.far = Infinity;
    if (raycaster.intersectObjects(objects, false).length === 0) seen++;
  }
  return seen / rays.length;
}

// The sun's visibility over the pixel window's footprint on the ground around p: 0 everywhere is
// the umbra, 1 everywhere full sun; anything else a penumbra or an edge, no clean comparison.
function footprintVisibility(p, sun, pixels) {
  const h = renderer.getContext().drawingBufferHeight;
  const perPixel = (p.distanceTo(camera.position) * 2 * Math.tan(THREE.MathUtils.degToRad(camera.fov / 2))) / h;
  // The ground is seen obliquely: stretch along the view direction's ground projection.
  const cosView = Math.max(0.2, (camera.position.y - p.y) / p.distanceTo(camera.position));
  const r = (pixels * perPixel) / cosView;
  let lo = 1, hi = 0;
  for (let k = 0; k <= 8; k++) {
    const q = k === 0 ? p : p.clone().add(new THREE.Vector3(r * Math.cos((k * Math.PI) / 4), 0, r * Math.sin((k * Math.PI) / 4)));
    const v = visibility(q, sun.direction, sun.angularRadius);
    lo = Math.min(lo, v);
    hi = Math.max(hi, v);
  }
  return hi === 0 ? "umbra" : lo === 1 ? "sunlit" : "edge";
}

function measureNow({ at = [] } = {}) {
  const set = client.lastSet;
  const plan = client.lastPlan;
  if (!set || !plan) throw new Error("no LightSet yet");
  const shadowed = plan.shadowed;
  const vis = (p) => Object.fromEntries(shadowed.map((l) => [l.id, visibility(p, l.direction, l.angularRadius)]));
  // The dominant shadowed light on the ground: its shadow of each object's centre.
  const sun = shadowed.reduce((b, l) => (!b || l.intensity * l.direction[1] > b.intensity * b.direction[1] ? l : b), null);
  const R = 3;
  const frame = readFrame();
  const sample = (p, withV = true) => ({
    point: p.toArray(),
    seen: cameraSees(p),
    ...radianceAt(frame, p, R),
    ...(withV ? { V: vis(p) } : {}),
    sunlight: sun ? footprintVisibility(p, sun, R + 2) : "none",
  });
  const objs = objects.map((o) => {
    if (!sun || sun.direction[1] < 0.05) return { name: o.name, usable: false };
    const d = new THREE.Vector3(...sun.direction);
    const p = o.position.clone().addScaledVector(d, -o.position.y / d.y);
    p.y = 0;
    const s = sample(p);
    return { name: o.name, usable: s.seen && s.onScreen, ...s };
  });
  // Open ground: the nearest grid point to the first usable shadow point that every shadowed light
  // sees, the camera sees, and no object stands near.
  const ref = objs.find((o) => o.usable)?.point ?? [0, 0, 2];
  const candidates = [];
  for (let x = -5; x <= 5; x += 0.5) for (let z = -5; z <= 4; z += 0.5) candidates.push(new THREE.Vector3(x, 0, z));
  candidates.sort((a, b) => a.distanceTo(new THREE.Vector3(...ref)) - b.distanceTo(new THREE.Vector3(...ref)));
  let open = null;
  for (const p of candidates) {
    if (objects.some((o) => Math.hypot(o.position.x - p.x, o.position.z - p.z) < 1.5)) continue;
    const s = sample(p);
    const lit = shadowed.every((l) => l.direction[1] <= 0 || s.V[l.id] === 1);
    if (!s.seen || !s.onScreen || !lit || s.sunlight !== "sunlit") continue;
    open = s;
    break;
  }
  return {
    seq: set.seq,
    tonemap,
    exposure: renderer.toneMappingExposure,
    set: {
      seq: set.seq,
      lights: set.lights.map(({ id, to_light, irradiance, angular_radius, shadowed }) => ({ id, to_light, irradiance, angular_radius, shadowed })),
      sh9: set.sh9 ?? null,
      sh9_unshadowed: set.sh9_unshadowed ?? null,
    },
    shadowed: shadowed.map(({ id, direction, intensity }) => ({ id, direction, intensity })),
    // `drawn`: the sun's direction as rendered (smoothed toward the plan's), so that a caller can
    // wait until the frame shows what the plan says.
    sun: sun ? { id: sun.id, direction: sun.direction, drawn: client.slots.find((s) => s.id === sun.id)?.dir.toArray() ?? null } : null,
    objects: objs,
    open,
    at: at.map((p) => sample(new THREE.Vector3(...p), false)),
  };
}

function state() {
  let directional = 0, casting = 0, probes = 0;
  scene.traverse((o) => {
    if (o.isDirectionalLight) {
      directional++;
      if (o.castShadow) casting++;
    }
    if (o.isLightProbe) probes++;
  });
  return {
    frames,
    fps: fps(),
    budget: { ...budget },
    streamUrl: client.streamUrl(),
    stats: { ...client.stats },
    lightsInSet: client.lastSet?.lights.length ?? 0,
    shadowedIds: client.shadowedLights.map((s) => s.id),
    shadowedCount: client.shadowedLights.length,
    directionalLights: directional,
    shadowCasting: casting,
    probes,
    canvas: [renderer.domElement.width, renderer.domElement.height],
    renderer: rendererName(),
    errors: [...errors],
  };
}

function rendererName() {
  const gl = renderer.getContext();
  const ext = gl.getExtension("WEBGL_debug_renderer_info");
  return ext ? gl.getParameter(ext.UNMASKED_RENDERER_WEBGL) : gl.getParameter(gl.RENDERER);
}

window.vemlightDemo = {
  state,
  client,
  /**
   * Resolves after the next frame with the pixel measurement (see measureNow). `snap: true` draws
   * that frame with the smoothing completed, so the pixels show the last set as it is.
   */
  measure: (options) => new Promise((resolve, reject) => pending.push({ options, resolve, reject })),
  /** Frames drawn in the next `ms` milliseconds, per second. */
  countFrames: (ms = 3000) =>
    new Promise((resolve) => {
      const f0 = frames, t0 = performance.now();
      setTimeout(() => resolve(((frames - f0) * 1000) / (performance.now() - t0)), ms);
    }),
  setBudget: (b) => {
    for (const [id, v] of Object.entries(b)) {
      const sel = $(id === "maxError" ? "max_error" : id);
      if (![...sel.options].some((o) => o.value === String(v ?? ""))) sel.add(new Option(String(v)));
      sel.value = String(v ?? "");
    }
    onBudget();
  },
};
