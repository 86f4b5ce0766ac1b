// vemlight-three: keeps a three.js scene lit by a vemlight daemon's `/v1/stream`.
//
// The K lights the daemon marks `shadowed` (or, from a daemon that does not mark them, the K with
// the largest irradiance) drive a pool of shadow-casting DirectionalLights; everything else reaches
// the scene as one LightProbe holding the remainder's L2 SH. The conversion from a LightSet to
// three.js parameters is written down in README.md ("Units"): DirectionalLight color × intensity =
// the light's irradiance, LightProbe coefficients = the radiance SH as sent, both with no factor
// of π, because three.js's Lambert shading is albedo/π · (Σ color·intensity·max(0, n·l) +
// shGetIrradianceAt(n)), which is DESIGN.md's diffuse formula term for term.
//
// The pure functions (`directionalParams`, `chooseShadowed`, `remainderSh`, `planSet`,
// `shadowRadius`, `shBasis`) hold the whole conversion and are what test/conversion.test.js checks;
// `VemlightLights` adds the transport, the pool, smoothing and the shadow cameras.

import { DirectionalLight, Group, LightProbe, Matrix4, Vector3 } from "three";

/** The WebSocket subprotocol of `/v1/stream` (src/lightset.rs `SUBPROTOCOL`). */
export const SUBPROTOCOL = "vemlight.v1";

/** Rec. 709 luminance of a linear RGB triple: the weight used to rank lights. */
export function luminance(rgb) {
  return 0.2126 * rgb[0] + 0.7152 * rgb[1] + 0.0722 * rgb[2];
}

/**
 * The nine real SH basis functions at unit vector (x, y, z), in the wire's order, which is three.js's
 * `SphericalHarmonics3.getBasisAt` (index l(l+1)+m; proto/lightset.schema.json `sh9`).
 */
export function shBasis(x, y, z, out = new Array(9)) {
  out[0] = 0.282095;
  out[1] = 0.488603 * y;
  out[2] = 0.488603 * z;
  out[3] = 0.488603 * x;
  out[4] = 1.092548 * x * y;
  out[5] = 1.092548 * y * z;
  out[6] = 0.315392 * (3 * z * z - 1);
  out[7] = 1.092548 * x * z;
  out[8] = 0.546274 * (x * x - y * y);
  return out;
}

function unit(v) {
  const n = Math.hypot(v[0], v[1], v[2]);
  return n > 0 ? [v[0] / n, v[1] / n, v[2] / n] : [0, 1, 0];
}

/**
 * One light of a LightSet as DirectionalLight parameters. three.js's RE_Direct_Lambert adds
 * `dotNL * directLight.color` (color × intensity) to the irradiance it multiplies by
 * BRDF_Lambert = albedo/π, so color × intensity is the light's irradiance as sent. The largest
 * channel goes into `intensity` and the colour keeps the chromaticity (as the glTF export does).
 * `direction` is `to_light`: three.js lights a surface from light.position − target.position.
 * `shadowDirection` is where the shadow map is drawn from: a two-part extent's core direction
 * (`extent.core_to_light`, the sun itself where the light, its cell's centroid, sits a little
 * aside: ALGORITHMS.md §12) where it lies within `ONE_MAP_CORE_DEG[0]` of `to_light`, `to_light`
 * from `ONE_MAP_CORE_DEG[1]` on, and turned part way between.
 */
export function directionalParams(light) {
  const [r, g, b] = light.irradiance;
  const intensity = Math.max(r, g, b, 0);
  const color = intensity > 0 ? [r / intensity, g / intensity, b / intensity] : [1, 1, 1];
  const direction = unit(light.to_light);
  return {
    id: light.id,
    direction,
    color,
    intensity,
    angularRadius: light.angular_radius ?? 0,
    shadowDirection: oneMapShadowDirection(direction, light.extent?.core_to_light),
  };
}

/**
 * Degrees: within the first, the one shadow map (of the light's `angular_radius`) is drawn from
 * the core's direction; from the second on, from `to_light`; between, turned from `to_light`
 * toward the core by the share of the angle that falls linearly from 1 to 0, so a core drifting
 * across the band moves the shadow smoothly. Farther cores (low suns whose cells hold much sky)
 * drew worse from the core (ALGORITHMS.md §12; the daemon's renderer uses the same band).
 */
export const ONE_MAP_CORE_DEG = Object.freeze([2, 4]);

function oneMapShadowDirection(direction, core) {
  if (!Array.isArray(core) || core.length !== 3 || !core.every(Number.isFinite)) return direction;
  if (Math.hypot(core[0], core[1], core[2]) === 0) return direction;
  const c = unit(core);
  const cos = c[0] * direction[0] + c[1] * direction[1] + c[2] * direction[2];
  const angle = Math.acos(Math.min(1, Math.max(-1, cos)));
  const [full, none] = ONE_MAP_CORE_DEG.map((d) => (d * Math.PI) / 180);
  const share = Math.min(1, Math.max(0, (none - angle) / (none - full)));
  if (share >= 1) return c;
  if (share <= 0) return direction;
  // Turned by share · angle in the plane of the two.
  const across = unit([c[0] - direction[0] * cos, c[1] - direction[1] * cos, c[2] - direction[2] * cos]);
  const t = share * angle;
  return unit([0, 1, 2].map((i) => direction[i] * Math.cos(t) + across[i] * Math.sin(t)));
}

/**
 * The lights that get a shadow map. A daemon asked for `shadowed=K` marks them (`shadowed: true`);
 * otherwise the min(K, n) with the largest irradiance (luminance), where a light shadowed last
 * time counts `stickiness` times its luminance, so that two lights of nearly equal weight do not
 * trade shadow maps every set. Returns `{ lights, fromServer }`.
 */
export function chooseShadowed(set, k, previousIds = new Set(), stickiness = 1.25) {
  const lights = set.lights ?? [];
  if (lights.some((l) => typeof l.shadowed === "boolean")) {
    return { lights: lights.filter((l) => l.shadowed === true), fromServer: true };
  }
  const score = (l) => luminance(l.irradiance) * (previousIds.has(l.id) ? stickiness : 1);
  const ranked = lights
    .filter((l) => luminance(l.irradiance) > 0)
    .sort((a, b) => score(b) - score(a) || a.id - b.id);
  return { lights: ranked.slice(0, Math.max(0, Math.min(k, ranked.length))), fromServer: false };
}

/**
 * The L2 radiance SH of everything but the shadowed lights, 27 floats in the wire's layout
 * ([c0.r, c0.g, c0.b, c1.r, …]). A daemon's `sh9_unshadowed` is used as sent; without it, `sh9`
 * minus each shadowed light's projection (a light of irradiance E toward l has coefficients
 * E·Y_lm(l)), which is how the daemon defines `sh9_unshadowed`; without `sh9` either, the
 * projection of the unshadowed lights themselves.
 */
export function remainderSh(set, shadowedLights) {
  if (Array.isArray(set.sh9_unshadowed) && set.sh9_unshadowed.length === 27) {
    return Float64Array.from(set.sh9_unshadowed);
  }
  const shadowedIds = new Set(shadowedLights.map((l) => l.id));
  const out = new Float64Array(27);
  const hasSh = Array.isArray(set.sh9) && set.sh9.length === 27;
  if (hasSh) out.set(set.sh9);
  const y = new Array(9);
  for (const l of set.lights ?? []) {
    const shadowed = shadowedIds.has(l.id);
    if (hasSh !== shadowed) continue; // with sh9: subtract the shadowed; without: add the rest
    const sign = hasSh ? -1 : 1;
    const [dx, dy, dz] = unit(l.to_light);
    shBasis(dx, dy, dz, y);
    for (let i = 0; i < 9; i++) {
      for (let c = 0; c < 3; c++) out[3 * i + c] += sign * l.irradiance[c] * y[i];
    }
  }
  return out;
}

/**
 * A LightSet as three.js parameters: the shadowed lights (`directionalParams` each) and the
 * LightProbe's coefficients (`remainderSh`, used with intensity 1: three.js's shGetIrradianceAt
 * multiplies band l by π, 2π/3, π/4, which turns radiance coefficients into irradiance).
 */
export function planSet(set, k, previousIds = new Set()) {
  const { lights, fromServer } = chooseShadowed(set, k, previousIds);
  return {
    shadowed: lights.map(directionalParams),
    sh: remainderSh(set, lights),
    fromServer,
  };
}

/**
 * PCF radius, in shadow-map texels, of the penumbra a light of angular radius `angularRadius`
 * casts at `occluderDistance` (world units) behind an occluder: the half-width of the penumbra is
 * d·tan(α), and one texel spans `frustumWidth / mapSize`. Clamped to [1, maxRadius]: the sun's
 * 0.27° gives the 1-texel floor, a wide patch of sky the cap (three.js's 5-tap Vogel disk gets
 * noisy beyond it).
 */
export function shadowRadius(angularRadius, { mapSize, frustumWidth, occluderDistance, maxRadius = 8 }) {
  const texel = frustumWidth / mapSize;
  const r = (occluderDistance * Math.tan(Math.min(angularRadius, 1.2))) / texel;
  return Math.min(maxRadius, Math.max(1, Number.isFinite(r) ? r : 1));
}

/**
 * How old a set is, in ms, robust to a clock skew between daemon and client: the smallest
 * (arrival − t_emit) seen on the connection stands for skew + the quickest delivery, and is taken
 * off (arrival − t_capture). Returns `{ ageMs, offsetMs }` with the updated offset.
 */
export function setAge(set, arrivalMs, offsetMs = Infinity) {
  const emitMs = Number(set.t_emit_ns ?? set.t_capture_ns ?? 0) / 1e6;
  const captureMs = Number(set.t_capture_ns ?? set.t_emit_ns ?? 0) / 1e6;
  const offset = Math.min(offsetMs, arrivalMs - emitMs);
  return { ageMs: arrivalMs - captureMs - offset, offsetMs: offset };
}

const _m = new Matrix4();
const _v = new Vector3();
const _size = new Vector3();
const _corner = new Vector3();
const _from = new Vector3();

/**
 * Subscribes to a daemon's `/v1/stream` and keeps `scene` lit by it. Call `update(dt)` once a frame
 * (before rendering) and `dispose()` when done. See README.md and vemlight-three.d.ts.
 */
export class VemlightLights {
  constructor(scene, options = {}) {
    this.options = {
      url: null,
      token: null,
      lights: 16,
      shadowed: 4,
      maxError: null,
      target: null,
      mapSize: 1024,
      maxRadius: 8,
      occluderDistance: null,
      smoothingS: 0.1,
      maxAgeMs: 1000,
      backoffMinMs: 250,
      backoffMaxMs: 10000,
      shadowBias: -0.0005,
      shadowNormalBias: 0.02,
      WebSocket: globalThis.WebSocket,
      onSet: null,
      onStatus: null,
      ...options,
    };
    this.scene = scene;
    this.group = new Group();
    this.group.name = "vemlight";
    scene.add(this.group);
    this.probe = new LightProbe();
    this.probe.name = "vemlight remainder SH";
    this.group.add(this.probe);
    this.slots = [];
    this._sh = new Float64Array(27);
    this._shGoal = new Float64Array(27);
    this._shSeeded = false;
    this.stats = {
      connected: false,
      wire: "unknown",
      seq: null,
      received: 0,
      applied: 0,
      droppedOld: 0,
      droppedOutOfOrder: 0,
      reconnects: 0,
      lastError: null,
    };
    this.lastSet = null;
    this._ws = null;
    this._timer = null;
    this._attempt = 0;
    this._legacyQuery = false;
    this._disposed = false;
    this._lastSeq = null;
    this._clockOffsetMs = Infinity;
    this._resizePool(this._poolSize());
    if (this.options.url) this.connect();
  }

  /** The shadow-casting lights in use: `{ id, light }` for each slot holding a light. */
  get shadowedLights() {
    return this.slots.filter((s) => s.id !== null).map((s) => ({ id: s.id, light: s.light }));
  }

  /** Changes the budget (`lights`, `shadowed`, `maxError`) and reconnects. */
  setBudget({ lights, shadowed, maxError } = {}) {
    if (lights !== undefined) this.options.lights = lights;
    if (maxError !== undefined) this.options.maxError = maxError;
    if (shadowed !== undefined) this.options.shadowed = shadowed;
    if (this._poolSize() !== this.slots.length) this._resizePool(this._poolSize());
    if (this.options.url) {
      this._attempt = 0;
      this.connect();
    }
  }

  /** The stream URL with the budget, and the token as `access_token` (browsers send no headers). */
  streamUrl() {
    const o = this.options;
    const url = new URL(o.url, globalThis.location?.href);
    if (url.protocol === "http:") url.protocol = "ws:";
    if (url.protocol === "https:") url.protocol = "wss:";
    const q = url.searchParams;
    q.set("lights", String(o.lights));
    if (!this._legacyQuery) {
      q.set("shadowed", String(Math.min(o.shadowed, o.lights)));
      if (o.maxError != null) q.set("max_error", String(o.maxError));
    }
    if (o.token) q.set("access_token", o.token);
    return url.toString();
  }

  /** Opens (or reopens) the stream. */
  connect() {
    clearTimeout(this._timer);
    this._closeSocket();
    if (this._disposed) return;
    const ws = new this.options.WebSocket(this.streamUrl(), SUBPROTOCOL);
    this._ws = ws;
    // A new connection may be a restarted daemon: its sequence numbers and clock start afresh.
    this._lastSeq = null;
    this._clockOffsetMs = Infinity;
    let gotMessage = false;
    ws.onopen = () => {
      this.stats.connected = true;
      this._status("connected");
    };
    ws.onmessage = (e) => {
      gotMessage = true;
      this._attempt = 0;
      let set;
      try {
        set = JSON.parse(e.data);
      } catch (err) {
        this.stats.lastError = `bad message: ${err.message}`;
        return;
      }
      this.applySet(set);
    };
    ws.onclose = (e) => {
      if (this._ws !== ws) return;
      this._ws = null;
      this.stats.connected = false;
      if (this._disposed) return;
      // A daemon that predates `shadowed` and `max_error` refuses them at the handshake (a close
      // before any message): ask again without them and choose the shadowed lights here.
      const refused = !gotMessage && !this._legacyQuery && this.stats.wire !== "server";
      if (refused) this._legacyQuery = true;
      const delay = refused
        ? 0
        : Math.min(this.options.backoffMaxMs, this.options.backoffMinMs * 2 ** this._attempt++) *
          (0.75 + 0.5 * Math.random());
      this._status(`disconnected (${e.code}); retrying in ${Math.round(delay)} ms`);
      this.stats.reconnects++;
      this._timer = setTimeout(() => this.connect(), delay);
    };
  }

  /**
   * Takes one LightSet (what the stream delivers; public for other transports and tests). Drops
   * one older than `maxAgeMs` or not newer than the last; returns whether it was applied.
   */
  applySet(set, arrivalMs = Date.now()) {
    this.stats.received++;
    if (this._lastSeq != null && set.seq !== 0 && set.seq <= this._lastSeq) {
      this.stats.droppedOutOfOrder++;
      return false;
    }
    const age = setAge(set, arrivalMs, this._clockOffsetMs);
    this._clockOffsetMs = age.offsetMs;
    if (age.ageMs > this.options.maxAgeMs) {
      this.stats.droppedOld++;
      return false;
    }
    const previous = new Set(this.slots.filter((s) => s.id !== null).map((s) => s.id));
    const plan = planSet(set, this.slots.length, previous);
    this.stats.wire = plan.fromServer ? "server" : this._legacyQuery ? "legacy" : "client";
    this._assign(plan.shadowed);
    this._shGoal.set(plan.sh);
    if (!this._shSeeded) {
      this._sh.set(plan.sh);
      this._shSeeded = true;
    }
    this._lastSeq = set.seq;
    this.stats.seq = set.seq;
    this.stats.applied++;
    this.lastSet = set;
    this.lastPlan = plan;
    this.options.onSet?.(set, plan);
    return true;
  }

  /**
   * Advances the smoothing by `dt` seconds (directions, intensities and the SH approach the last
   * set with time constant `smoothingS`) and fits the shadow cameras. Call once a frame.
   */
  update(dt = 1 / 60) {
    const tau = this.options.smoothingS;
    const a = tau > 0 ? 1 - Math.exp(-Math.max(0, dt) / tau) : 1;
    for (const s of this.slots) {
      s.dir.lerp(s.goalDir, a).normalize();
      s.shadowDir.lerp(s.goalShadowDir, a).normalize();
      for (let c = 0; c < 3; c++) s.irr[c] += (s.goalIrr[c] - s.irr[c]) * a;
      const peak = Math.max(s.irr[0], s.irr[1], s.irr[2], 0);
      s.light.intensity = peak;
      if (peak > 0) s.light.color.setRGB(s.irr[0] / peak, s.irr[1] / peak, s.irr[2] / peak);
      if (s.id === null && peak < 1e-6 * (this._peak || 1)) s.light.intensity = 0;
      this._fitShadow(s);
    }
    for (let i = 0; i < 27; i++) this._sh[i] += (this._shGoal[i] - this._sh[i]) * a;
    const coef = this.probe.sh.coefficients;
    for (let i = 0; i < 9; i++) coef[i].set(this._sh[3 * i], this._sh[3 * i + 1], this._sh[3 * i + 2]);
    this.probe.intensity = 1;
  }

  /** Closes the stream and removes and frees the lights (and their shadow maps). */
  dispose() {
    this._disposed = true;
    clearTimeout(this._timer);
    this._closeSocket();
    this._resizePool(0);
    this.group.remove(this.probe);
    this.probe.dispose?.();
    this.scene.remove(this.group);
  }

  _status(text) {
    this.options.onStatus?.(text, this.stats);
  }

  _closeSocket() {
    const ws = this._ws;
    this._ws = null;
    if (ws) {
      ws.onclose = ws.onmessage = ws.onopen = null;
      try {
        ws.close(1000);
      } catch {
        // already closed
      }
    }
    this.stats.connected = false;
  }

  // One DirectionalLight per shadowed light the stream can send: min(K, N).
  _poolSize() {
    return Math.max(0, Math.min(this.options.shadowed, this.options.lights));
  }

  _resizePool(k) {
    while (this.slots.length > k) {
      const s = this.slots.pop();
      this.group.remove(s.light, s.light.target);
      s.light.dispose();
    }
    while (this.slots.length < k) {
      const light = new DirectionalLight(0xffffff, 0);
      light.name = `vemlight shadowed ${this.slots.length}`;
      light.castShadow = true;
      light.shadow.mapSize.set(this.options.mapSize, this.options.mapSize);
      light.shadow.bias = this.options.shadowBias;
      light.shadow.normalBias = this.options.shadowNormalBias;
      this.group.add(light, light.target);
      const slot = {
        id: null,
        light,
        dir: new Vector3(0, 1, 0),
        goalDir: new Vector3(0, 1, 0),
        shadowDir: new Vector3(0, 1, 0),
        goalShadowDir: new Vector3(0, 1, 0),
        // Where the shadow camera stands (`_fitShadow`), in the form LightShadow.updateMatrices
        // reads a light: three.js puts the camera at the light and shades from it too, and the
        // two differ where the light has a core direction of its own.
        shadowFrom: { matrixWorld: new Matrix4(), target: light.target },
        // Whether `_fitShadow` has placed `shadowFrom` (until then the light itself stands in).
        fitted: false,
        irr: [0, 0, 0],
        goalIrr: [0, 0, 0],
        angularRadius: 0,
      };
      const updateMatrices = light.shadow.updateMatrices;
      light.shadow.updateMatrices = function (l) {
        updateMatrices.call(this, slot.fitted ? slot.shadowFrom : l);
      };
      this.slots.push(slot);
    }
  }

  // Lights keep their slot (and so their shadow map) while their id stays shadowed; a new id takes
  // a free slot, jumps to its direction and fades in from 0, while the probe, which loses it at the
  // same rate, keeps the sum.
  _assign(shadowed) {
    const byId = new Map(shadowed.map((p) => [p.id, p]));
    for (const s of this.slots) {
      if (s.id !== null && !byId.has(s.id)) {
        s.id = null;
        s.goalIrr = [0, 0, 0];
      }
    }
    const placed = new Set(this.slots.map((s) => s.id));
    const free = this.slots.filter((s) => s.id === null);
    for (const p of shadowed) {
      if (placed.has(p.id)) continue;
      const s = free.shift();
      if (!s) break;
      s.id = p.id;
      s.dir.fromArray(p.direction);
      s.shadowDir.fromArray(p.shadowDirection ?? p.direction);
      s.irr = [0, 0, 0];
    }
    this._peak = 0;
    for (const s of this.slots) {
      const p = s.id === null ? null : byId.get(s.id);
      if (!p) continue;
      s.goalDir.fromArray(p.direction);
      s.goalShadowDir.fromArray(p.shadowDirection ?? p.direction);
      s.goalIrr = p.color.map((c) => c * p.intensity);
      s.angularRadius = p.angularRadius;
      this._peak = Math.max(this._peak, p.intensity);
    }
  }

  // The light sits outside the target box toward `dir`, its shadow camera toward `shadowDir`
  // (`shadowFrom`); the orthographic camera is fitted to the box's eight corners seen from there,
  // so the map's texels cover the box and nothing else.
  _fitShadow(s) {
    const box = this.options.target;
    if (!box || box.isEmpty()) return;
    const center = box.getCenter(_v);
    const radius = box.getSize(_size).length() / 2;
    s.light.position.copy(s.dir).multiplyScalar(radius + 1).add(center);
    s.light.target.position.copy(center);
    s.light.updateMatrixWorld();
    s.light.target.updateMatrixWorld();
    const from = _from.copy(s.shadowDir).multiplyScalar(radius + 1).add(center);
    s.shadowFrom.matrixWorld.makeTranslation(from.x, from.y, from.z);
    s.fitted = true;
    const cam = s.light.shadow.camera;
    cam.position.copy(from);
    cam.lookAt(center);
    cam.updateMatrixWorld();
    _m.copy(cam.matrixWorld).invert();
    let minX = Infinity, minY = Infinity, minZ = Infinity;
    let maxX = -Infinity, maxY = -Infinity, maxZ = -Infinity;
    for (let i = 0; i < 8; i++) {
      const p = _corner.set(
        i & 1 ? box.max.x : box.min.x,
        i & 2 ? box.max.y : box.min.y,
        i & 4 ? box.max.z : box.min.z,
      ).applyMatrix4(_m);
      minX = Math.min(minX, p.x); maxX = Math.max(maxX, p.x);
      minY = Math.min(minY, p.y); maxY = Math.max(maxY, p.y);
      minZ = Math.min(minZ, p.z); maxZ = Math.max(maxZ, p.z);
    }
    cam.left = minX;
    cam.right = maxX;
    cam.bottom = minY;
    cam.top = maxY;
    cam.near = Math.max(0.01, -maxZ - 0.1);
    cam.far = -minZ + 0.1;
    cam.updateProjectionMatrix();
    const d = this.options.occluderDistance ?? (box.max.y - box.min.y) / 2;
    s.light.shadow.radius = shadowRadius(s.angularRadius, {
      mapSize: this.options.mapSize,
      frustumWidth: Math.max(maxX - minX, maxY - minY),
      occluderDistance: d,
      maxRadius: this.options.maxRadius,
    });
  }
}
