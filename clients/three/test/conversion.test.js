// The LightSet → three.js conversion (README.md "Units"), against the pinned three.js itself.
// Run: `npm test` (or `node --import ./test/register.mjs --test test/conversion.test.js`); the
// daemon's tests run it too (tests/demo_browser.rs).

import assert from "node:assert/strict";
import { readFileSync } from "node:fs";
import { mock, test } from "node:test";
import * as THREE from "three";
import {
  SUBPROTOCOL,
  VemlightLights,
  chooseShadowed,
  directionalParams,
  ONE_MAP_CORE_DEG,
  planSet,
  remainderSh,
  setAge,
  shBasis,
  shadowRadius,
} from "../vemlight-three.js";

const here = (p) => new URL(p, import.meta.url);
const vendored = readFileSync(here("../vendor/three.module.min.js"), "utf8");

// DESIGN.md's diffuse formula, the reference: L_out = albedo/π · Σ E_k · max(0, n·l_k) · V_k.
const dot = (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
function designDiffuse(lights, n, albedo = 1) {
  const out = [0, 0, 0];
  for (const l of lights) {
    const c = Math.max(0, dot(n, l.to_light));
    for (let i = 0; i < 3; i++) out[i] += (albedo / Math.PI) * l.irradiance[i] * c;
  }
  return out;
}

// three.js's shGetIrradianceAt (lights_pars_begin.glsl.js), transcribed; the test "the shader
// lines the conversion rests on" pins the GLSL it is transcribed from.
function shGetIrradianceAt(n, c /* 27 floats */) {
  const [x, y, z] = n;
  const w = [
    0.886227,
    2.0 * 0.511664 * y,
    2.0 * 0.511664 * z,
    2.0 * 0.511664 * x,
    2.0 * 0.429043 * x * y,
    2.0 * 0.429043 * y * z,
    0.743125 * z * z - 0.247708,
    2.0 * 0.429043 * x * z,
    0.429043 * (x * x - y * y),
  ];
  const out = [0, 0, 0];
  for (let i = 0; i < 9; i++) for (let k = 0; k < 3; k++) out[k] += c[3 * i + k] * w[i];
  return out;
}

// What three.js's MeshLambertMaterial computes for a normal n from the parameters the client
// sets: RE_Direct_Lambert (dotNL · color·intensity · BRDF_Lambert) for each DirectionalLight,
// RE_IndirectDiffuse_Lambert (shGetIrradianceAt(n, probe · intensity) · BRDF_Lambert) for the probe.
function threeLambert(plan, n, albedo = 1, probeIntensity = 1) {
  const out = [0, 0, 0];
  for (const p of plan.shadowed) {
    const c = Math.max(0, dot(n, p.direction));
    for (let i = 0; i < 3; i++) out[i] += (albedo / Math.PI) * p.color[i] * p.intensity * c;
  }
  const e = shGetIrradianceAt(n, plan.sh.map((v) => v * probeIntensity));
  for (let i = 0; i < 3; i++) out[i] += (albedo / Math.PI) * e[i];
  return out;
}

// A deterministic sky: a bright sun and n − 1 patches spread over the upper hemisphere.
function unitArray(v) {
  const n = Math.hypot(...v);
  return v.map((x) => x / n);
}

function makeSet(n = 16, { seq = 1, sunId = 3, withSh = true, nowNs = BigInt(Date.now()) * 1000000n } = {}) {
  const lights = [];
  for (let i = 0; i < n; i++) {
    const t = (i + 0.5) / n;
    const el = Math.asin(Math.max(0.05, t));
    const az = i * 2.399963;
    const d = [Math.cos(el) * Math.cos(az), Math.sin(el), -Math.cos(el) * Math.sin(az)];
    const sun = i === sunId;
    lights.push({
      id: i,
      to_light: sun ? [0.6, 0.5, -Math.sqrt(1 - 0.61)] : d,
      irradiance: sun ? [30, 27, 22] : [0.4 + 0.03 * i, 0.5 + 0.02 * i, 0.8],
      solid_angle: sun ? 6.8e-5 : (2 * Math.PI) / n,
      angular_radius: sun ? 0.0046 : 0.35,
    });
  }
  const set = {
    schema: "vemlight.lightset/1",
    seq,
    frame: seq,
    t_capture_ns: Number(nowNs - 20000000n),
    t_emit_ns: Number(nowNs - 5000000n),
    lights,
  };
  if (withSh) {
    // The SH of a map made of these lights exactly: Σ E_k Y(l_k).
    set.sh9 = new Array(27).fill(0);
    const y = new Array(9);
    for (const l of lights) {
      shBasis(...l.to_light, y);
      for (let i = 0; i < 9; i++) for (let c = 0; c < 3; c++) set.sh9[3 * i + c] += l.irradiance[c] * y[i];
    }
  }
  return set;
}

const normals = [];
for (let i = 0; i < 200; i++) {
  const z = 1 - (2 * (i + 0.5)) / 200;
  const r = Math.sqrt(1 - z * z);
  const phi = i * 2.399963;
  normals.push([r * Math.cos(phi), z, r * Math.sin(phi)]);
}

test("the shader lines the conversion rests on are those of the pinned three.js", () => {
  const pinned = JSON.parse(readFileSync(here("../package.json"), "utf8")).devDependencies.three;
  assert.equal(readFileSync(here("../vendor/VERSION"), "utf8").trim(), pinned);
  assert.equal(`0.${THREE.REVISION}.0`, pinned, "vendor/ holds the pinned three.js (run vendor.sh)");
  for (const line of [
    // lights_pars_begin.glsl.js: shGetIrradianceAt, i.e. E(n) = Σ A_l L_lm Y_lm(n).
    "vec3 result = shCoefficients[ 0 ] * 0.886227;",
    "result += shCoefficients[ 1 ] * 2.0 * 0.511664 * y;",
    "result += shCoefficients[ 2 ] * 2.0 * 0.511664 * z;",
    "result += shCoefficients[ 3 ] * 2.0 * 0.511664 * x;",
    "result += shCoefficients[ 4 ] * 2.0 * 0.429043 * x * y;",
    "result += shCoefficients[ 5 ] * 2.0 * 0.429043 * y * z;",
    "result += shCoefficients[ 6 ] * ( 0.743125 * z * z - 0.247708 );",
    "result += shCoefficients[ 7 ] * 2.0 * 0.429043 * x * z;",
    "result += shCoefficients[ 8 ] * 0.429043 * ( x * x - y * y );",
    "vec3 irradiance = shGetIrradianceAt( worldNormal, lightProbe );",
    // lights_fragment_begin.glsl.js: the probe adds to the indirect irradiance.
    "irradiance += getLightProbeIrradiance( lightProbe, geometryNormal );",
    // common.glsl.js: BRDF_Lambert = albedo/π.
    "return RECIPROCAL_PI * diffuseColor;",
    // lights_lambert_pars_fragment.glsl.js: direct and indirect Lambert terms.
    "vec3 irradiance = dotNL * directLight.color;",
    "reflectedLight.directDiffuse += irradiance * BRDF_Lambert( material.diffuseColor );",
    "reflectedLight.indirectDiffuse += irradiance * BRDF_Lambert( material.diffuseColor );",
  ]) {
    assert.ok(vendored.includes(line), `three.js ${pinned} no longer has: ${line}`);
  }
});

test("the wire's SH basis is three.js's SphericalHarmonics3.getBasisAt", () => {
  const b = new Array(9);
  for (const n of normals) {
    THREE.SphericalHarmonics3.getBasisAt(new THREE.Vector3(...n), b);
    const ours = shBasis(...n);
    for (let i = 0; i < 9; i++) assert.ok(Math.abs(b[i] - ours[i]) < 1e-12, `Y${i} at ${n}`);
  }
});

test("three.js's own SH irradiance is the transcribed shader's", () => {
  const set = makeSet();
  const sh = new THREE.SphericalHarmonics3();
  for (let i = 0; i < 9; i++) sh.coefficients[i].set(set.sh9[3 * i], set.sh9[3 * i + 1], set.sh9[3 * i + 2]);
  const t = new THREE.Vector3();
  for (const n of normals) {
    sh.getIrradianceAt(new THREE.Vector3(...n), t);
    const e = shGetIrradianceAt(n, set.sh9);
    assert.ok(Math.abs(t.x - e[0]) < 1e-4 * (1 + Math.abs(e[0])));
    assert.ok(Math.abs(t.z - e[2]) < 1e-4 * (1 + Math.abs(e[2])));
  }
});

test("a DirectionalLight's color × intensity is the light's irradiance, its direction to_light", () => {
  const l = { id: 7, to_light: [0, 2, 0], irradiance: [3, 6, 1.5], solid_angle: 0.1, angular_radius: 0.2 };
  const p = directionalParams(l);
  assert.deepEqual(p.direction, [0, 1, 0]);
  assert.equal(p.intensity, 6);
  assert.deepEqual(p.color.map((c) => c * p.intensity), [3, 6, 1.5]);
  assert.equal(p.angularRadius, 0.2);
  // A light on a flat surface facing it gives albedo/π · irradiance: DESIGN.md's formula, no π.
  const plan = { shadowed: [p], sh: new Float64Array(27) };
  assert.deepEqual(threeLambert(plan, [0, 1, 0], 0.5), [0.5 / Math.PI * 3, 0.5 / Math.PI * 6, 0.5 / Math.PI * 1.5]);
});

test("K shadowed lights + the remainder probe shade exactly as the lights, the remainder through L2", () => {
  const set = makeSet(16);
  for (const k of [0, 1, 4, 16]) {
    const plan = planSet(set, k);
    assert.equal(plan.shadowed.length, k);
    const shadowed = new Set(plan.shadowed.map((p) => p.id));
    for (const n of normals) {
      // Exact: the shadowed lights as they are, each other light through the L2 convolution of
      // its delta, Σ_lm A_l E Y_lm(l) Y_lm(n).
      const want = designDiffuse(set.lights.filter((l) => shadowed.has(l.id)), n);
      const yn = shBasis(...n);
      const A = [Math.PI, (2 * Math.PI) / 3, (2 * Math.PI) / 3, (2 * Math.PI) / 3, Math.PI / 4, Math.PI / 4, Math.PI / 4, Math.PI / 4, Math.PI / 4];
      for (const l of set.lights.filter((l) => !shadowed.has(l.id))) {
        const yl = shBasis(...l.to_light);
        let s = 0;
        for (let i = 0; i < 9; i++) s += A[i] * yl[i] * yn[i];
        for (let c = 0; c < 3; c++) want[c] += (l.irradiance[c] / Math.PI) * s;
      }
      const got = threeLambert(plan, n);
      for (let c = 0; c < 3; c++) assert.ok(Math.abs(got[c] - want[c]) < 1e-4 * (1 + want[c]), `k=${k} n=${n}: ${got} vs ${want}`);
    }
  }
});

test("with the sun shadowed the diffuse error against DESIGN.md's formula is small; SH alone is not", () => {
  const set = makeSet(16);
  const rms = (k) => {
    const plan = planSet(set, k);
    let e = 0, w = 0;
    for (const n of normals) {
      const want = designDiffuse(set.lights, n)[1];
      e += (threeLambert(plan, n)[1] - want) ** 2;
      w += want ** 2;
    }
    return Math.sqrt(e / w);
  };
  const shOnly = rms(0);
  const withSun = rms(1);
  assert.ok(withSun < 0.03, `K=1: ${withSun}`);
  assert.ok(shOnly > 2 * withSun, `SH alone ${shOnly} vs K=1 ${withSun}`);
  assert.ok(rms(16) < 1e-4);
});

test("the remainder: sh9_unshadowed as sent; else sh9 − shadowed; else the rest's projection", () => {
  const set = makeSet(8);
  const { lights } = chooseShadowed(set, 2);
  const fromSh = remainderSh(set, lights);
  const noSh = { ...set, sh9: undefined };
  const fromLights = remainderSh(noSh, lights);
  for (let i = 0; i < 27; i++) assert.ok(Math.abs(fromSh[i] - fromLights[i]) < 1e-9 * (1 + Math.abs(fromSh[i])));
  const sent = Array.from({ length: 27 }, (_, i) => i / 10);
  assert.deepEqual(Array.from(remainderSh({ ...set, sh9_unshadowed: sent }, lights)), sent);
});

test("the daemon's `shadowed` marks win; without them the largest, sticky", () => {
  const set = makeSet(8);
  const marked = { ...set, lights: set.lights.map((l) => ({ ...l, shadowed: l.id === 1 || l.id === 5 })) };
  const m = chooseShadowed(marked, 4);
  assert.equal(m.fromServer, true);
  assert.deepEqual(m.lights.map((l) => l.id), [1, 5]);
  const c = chooseShadowed(set, 2);
  assert.equal(c.fromServer, false);
  assert.equal(c.lights[0].id, 3, "the sun first");
  // Two near-equal lights: the one already shadowed keeps its map.
  const tie = {
    lights: [
      { id: 1, to_light: [0, 1, 0], irradiance: [1, 1, 1] },
      { id: 2, to_light: [1, 0, 0], irradiance: [1.1, 1.1, 1.1] },
    ],
  };
  assert.deepEqual(chooseShadowed(tie, 1).lights.map((l) => l.id), [2]);
  assert.deepEqual(chooseShadowed(tie, 1, new Set([1])).lights.map((l) => l.id), [1]);
  assert.equal(chooseShadowed(tie, 5).lights.length, 2, "min(K, n)");
});

test("soft-shadow radius from angular extent, in texels", () => {
  const o = { mapSize: 1024, frustumWidth: 10.24, occluderDistance: 1 };
  assert.equal(shadowRadius(0.0046, o), 1, "the sun: the 1-texel floor");
  assert.ok(Math.abs(shadowRadius(0.05, o) - 100 * Math.tan(0.05)) < 1e-9);
  assert.equal(shadowRadius(0.5, o), 8, "a wide patch: the cap");
});

test("set age is measured against the connection's clock offset", () => {
  const set = { t_capture_ns: 1_000_000_000, t_emit_ns: 1_010_000_000 };
  // Client clock 5 s ahead of the daemon's; arrives 2 ms after emission.
  let a = setAge(set, 1012 + 5000);
  assert.equal(a.offsetMs, 5002);
  assert.equal(a.ageMs, 10);
  a = setAge({ t_capture_ns: 2_000_000_000, t_emit_ns: 2_010_000_000 }, 2010 + 5000 + 900, a.offsetMs);
  assert.equal(a.ageMs, 908);
});

// A WebSocket stand-in: records what the client opens and lets the test deliver messages.
class FakeSocket {
  static opened = [];
  constructor(url, protocol) {
    this.url = url;
    this.protocol = protocol;
    this.closed = false;
    FakeSocket.opened.push(this);
  }
  close() {
    this.closed = true;
  }
  deliver(set) {
    this.onmessage?.({ data: JSON.stringify(set) });
  }
  drop(code = 1006) {
    this.onclose?.({ code });
  }
}

function client(extra = {}) {
  FakeSocket.opened = [];
  const scene = new THREE.Scene();
  const target = new THREE.Box3(new THREE.Vector3(-3, 0, -3), new THREE.Vector3(3, 2, 3));
  const c = new VemlightLights(scene, {
    url: "ws://daemon.test:7878/v1/stream",
    token: "t0k",
    lights: 16,
    shadowed: 4,
    target,
    WebSocket: FakeSocket,
    ...extra,
  });
  return { scene, c, target };
}

test("the scene gets K shadow-casting DirectionalLights and a LightProbe set as converted", () => {
  const { scene, c, target } = client();
  const ws = FakeSocket.opened[0];
  assert.equal(ws.protocol, SUBPROTOCOL);
  const url = new URL(ws.url);
  assert.equal(url.searchParams.get("lights"), "16");
  assert.equal(url.searchParams.get("shadowed"), "4");
  assert.equal(url.searchParams.get("access_token"), "t0k");
  const set = makeSet(16);
  ws.deliver(set);
  c.update(10); // long enough for the smoothing to arrive
  const dirs = [];
  scene.traverse((o) => o.isDirectionalLight && dirs.push(o));
  assert.equal(dirs.length, 4);
  assert.ok(dirs.every((d) => d.castShadow));
  const plan = planSet(set, 4);
  for (const p of plan.shadowed) {
    const { light } = c.shadowedLights.find((s) => s.id === p.id);
    const irr = [light.color.r, light.color.g, light.color.b].map((v) => v * light.intensity);
    for (let i = 0; i < 3; i++) assert.ok(Math.abs(irr[i] - p.color[i] * p.intensity) < 1e-6 * p.intensity);
    const d = light.position.clone().sub(light.target.position).normalize();
    assert.ok(d.distanceTo(new THREE.Vector3(...p.direction)) < 1e-9, "direction = to_light");
    // The fitted shadow camera sees every corner of the target box.
    const cam = light.shadow.camera;
    cam.updateMatrixWorld();
    const frustum = new THREE.Frustum().setFromProjectionMatrix(
      new THREE.Matrix4().multiplyMatrices(cam.projectionMatrix, cam.matrixWorldInverse),
    );
    for (let i = 0; i < 8; i++) {
      const corner = new THREE.Vector3(i & 1 ? target.max.x : target.min.x, i & 2 ? target.max.y : target.min.y, i & 4 ? target.max.z : target.min.z);
      assert.ok(frustum.containsPoint(corner.multiplyScalar(0.999)), `corner ${i}`);
    }
    assert.ok(light.shadow.radius >= 1 && light.shadow.radius <= 8);
  }
  const probe = [];
  scene.traverse((o) => o.isLightProbe && probe.push(o));
  assert.equal(probe.length, 1);
  assert.equal(probe[0].intensity, 1);
  for (let i = 0; i < 9; i++) {
    const co = probe[0].sh.coefficients[i];
    assert.ok(Math.abs(co.x - plan.sh[3 * i]) < 1e-6 * (1 + Math.abs(plan.sh[3 * i])));
  }
  assert.equal(c.stats.wire, "client");
  c.dispose();
  assert.ok(ws.closed);
  let left = 0;
  scene.traverse((o) => (o.isLight ? left++ : 0));
  assert.equal(left, 0, "dispose removes every light");
});

test("ids keep their shadow maps; a new id takes a freed slot; directions are smoothed", () => {
  const { c } = client({ shadowed: 2, smoothingS: 0.1 });
  const ws = FakeSocket.opened[0];
  const a = makeSet(6, { seq: 1 });
  // The sun (id 3) and the brightest patch.
  ws.deliver(a);
  c.update(10);
  const before = new Map(c.shadowedLights.map((s) => [s.id, s.light]));
  assert.equal(before.size, 2);
  assert.ok(before.has(3));
  // Next set: same ids, reversed order, the sun moved; another patch overtakes the second.
  const b = makeSet(6, { seq: 2 });
  b.lights.reverse();
  const sun = b.lights.find((l) => l.id === 3);
  sun.to_light = [0.8, 0.6, 0];
  const other = [...before.keys()].find((id) => id !== 3);
  const newcomer = b.lights.find((l) => l.id !== 3 && l.id !== other);
  newcomer.irradiance = [50, 50, 50];
  ws.deliver(b);
  const after = new Map(c.shadowedLights.map((s) => [s.id, s.light]));
  assert.equal(after.get(3), before.get(3), "the sun keeps its light (and shadow map)");
  assert.equal(after.get(newcomer.id), before.get(other), "the newcomer takes the freed light");
  // Smoothing: after one 1/60 s frame the sun has moved part of the way only.
  const light = after.get(3);
  const d0 = light.position.clone().sub(light.target.position).normalize();
  c.update(1 / 60);
  const d1 = light.position.clone().sub(light.target.position).normalize();
  const goal = new THREE.Vector3(0.8, 0.6, 0);
  assert.ok(d1.distanceTo(goal) < d0.distanceTo(goal) && d1.distanceTo(goal) > 0.5 * d0.distanceTo(goal));
  assert.ok(after.get(newcomer.id).intensity < 50 * 0.5, "the newcomer fades in");
  c.update(10);
  const d2 = light.position.clone().sub(light.target.position).normalize();
  assert.ok(d2.distanceTo(goal) < 1e-6);
  c.dispose();
});

test("a sun's core direction draws its shadow map; shading stays on to_light", () => {
  const { c } = client({ shadowed: 1 });
  const ws = FakeSocket.opened[0];
  const set = makeSet(6);
  const sun = set.lights.find((l) => l.id === 3);
  // The light (its cell's centroid) 1° off the sun it stands for; the core is the sun.
  const toLight = new THREE.Vector3(...sun.to_light).normalize();
  const across = toLight.clone().cross(new THREE.Vector3(0, 1, 0)).normalize();
  const turned = (deg) => toLight.clone().applyAxisAngle(across, (deg * Math.PI) / 180);
  const extent = (core) => ({ core_share: 0.8, core_radius: 0.0046, rest_radius: 0.05, core_to_light: core.toArray() });
  // Beyond the band (a low sun's core 4–11° from a light holding much sky) the map stays on
  // to_light; within it, the core's own; between, turned a·(4° − a)/2° from the light toward the
  // core, so a core moving 0.01° moves the map by at most 0.02° (no switch).
  const [full, none] = ONE_MAP_CORE_DEG;
  const angleDeg = (a, b) => new THREE.Vector3(...a).angleTo(new THREE.Vector3(...b)) * (180 / Math.PI);
  let last = null;
  for (let step = 0; step <= 600; step++) {
    const deg = step / 100;
    const core = turned(deg);
    sun.extent = extent(core);
    const p = directionalParams(sun);
    const share = Math.min(1, Math.max(0, (none - deg) / (none - full)));
    const fromLight = angleDeg(p.shadowDirection, p.direction);
    assert.ok(Math.abs(fromLight - deg * share) < 1e-4, `${deg}°: ${fromLight}° from the light`);
    assert.ok(Math.abs(angleDeg(p.shadowDirection, core.toArray()) - deg * (1 - share)) < 1e-4, `${deg}°: toward the core`);
    if (last) assert.ok(angleDeg(p.shadowDirection, last) <= 0.02 + 1e-6, `${deg}°: jumped`);
    last = p.shadowDirection;
  }
  sun.extent = extent(turned(none + 0.5));
  assert.deepEqual(directionalParams(sun).shadowDirection, directionalParams(sun).direction);
  const core = turned(full - 1);
  sun.extent = extent(core);
  assert.deepEqual(directionalParams(sun).shadowDirection, unitArray(core.toArray()));
  assert.deepEqual(directionalParams(set.lights[0]).shadowDirection, directionalParams(set.lights[0]).direction);
  ws.deliver(set);
  c.update(10);
  const { light } = c.shadowedLights[0];
  const shading = light.position.clone().sub(light.target.position).normalize();
  assert.ok(shading.distanceTo(new THREE.Vector3(...sun.to_light).normalize()) < 1e-6, "shading from to_light");
  // What the renderer does before drawing the map: the camera then looks down the core's direction.
  light.shadow.updateMatrices(light);
  const look = new THREE.Vector3();
  light.shadow.camera.getWorldDirection(look);
  assert.ok(look.negate().distanceTo(core) < 1e-6, `shadow from the core: ${look.toArray()}`);
  // And the shadow matrix maps the box's centre to the middle of the map.
  const mid = c.options.target.getCenter(new THREE.Vector3()).applyMatrix4(light.shadow.matrix);
  assert.ok(Math.abs(mid.x - 0.5) < 0.05 && Math.abs(mid.y - 0.5) < 0.05, `${mid.toArray()}`);
  c.dispose();
});

test("old and out-of-order sets are dropped", () => {
  const { c } = client({ maxAgeMs: 500 });
  const ws = FakeSocket.opened[0];
  const now = BigInt(Date.now()) * 1000000n;
  ws.deliver(makeSet(4, { seq: 10, nowNs: now }));
  ws.deliver(makeSet(4, { seq: 9, nowNs: now }));
  assert.equal(c.stats.droppedOutOfOrder, 1);
  // Captured 2 s before it was emitted (a stalled pipeline): too old.
  const stale = makeSet(4, { seq: 11, nowNs: now });
  stale.t_capture_ns -= 2e9;
  ws.deliver(stale);
  assert.equal(c.stats.droppedOld, 1);
  assert.equal(c.stats.seq, 10);
  c.dispose();
});

test("reconnects with backoff; a daemon refusing `shadowed` is asked again without it", () => {
  mock.timers.enable({ apis: ["setTimeout"] });
  try {
    const { c } = client({ maxError: 0.02, backoffMinMs: 100, backoffMaxMs: 1000 });
    const first = FakeSocket.opened[0];
    assert.equal(new URL(first.url).searchParams.get("max_error"), "0.02");
    first.drop(); // refused at the handshake: nothing received
    mock.timers.tick(0);
    const second = FakeSocket.opened[1];
    const q = new URL(second.url).searchParams;
    assert.equal(q.get("shadowed"), null);
    assert.equal(q.get("max_error"), null);
    second.deliver(makeSet(8, { seq: 1 }));
    assert.equal(c.stats.wire, "legacy");
    assert.equal(c.shadowedLights.length, 4, "shadowed chosen here");
    // Later drops back off: 100 ms, then 200 ms (±25 % jitter).
    second.drop();
    mock.timers.tick(60);
    assert.equal(FakeSocket.opened.length, 2);
    mock.timers.tick(70);
    assert.equal(FakeSocket.opened.length, 3);
    FakeSocket.opened[2].drop();
    mock.timers.tick(140);
    assert.equal(FakeSocket.opened.length, 3);
    mock.timers.tick(120);
    assert.equal(FakeSocket.opened.length, 4);
    c.dispose();
    mock.timers.tick(5000);
    assert.equal(FakeSocket.opened.length, 4, "no reconnect after dispose");
  } finally {
    mock.timers.reset();
  }
});
