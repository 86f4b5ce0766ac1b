// Type declarations of vemlight-three.js (see README.md). Frames and units: DESIGN.md — world
// frame +Y up, −Z forward, +X right (three.js's); `to_light` points toward the light; irradiance
// is linear RGB, the map's radiance × sr.

import type { Box3, DirectionalLight, Group, LightProbe, Object3D } from "three";

/** The WebSocket subprotocol of `/v1/stream`: "vemlight.v1". */
export declare const SUBPROTOCOL: "vemlight.v1";
/** Degrees: within `[0]` of its light a core's direction is where the one shadow map is drawn from, from `[1]` on the light's, turned part way between. */
export declare const ONE_MAP_CORE_DEG: readonly [number, number];

export type Vec3 = [number, number, number];

/** One light of a LightSet (proto/lightset.schema.json). */
export interface WireLight {
  id: number;
  to_light: Vec3;
  irradiance: Vec3;
  solid_angle: number;
  angular_radius: number;
  /** Present when the stream was asked `shadowed=K`: exactly min(K, lights.length) are true. */
  shadowed?: boolean;
  /** A two-part extent (a sun in its glow): the core's share and discs, and its own direction. */
  extent?: { core_share: number; core_radius: number; rest_radius: number; core_to_light?: Vec3 };
}

/** The parts of a LightSet this module reads; the document has more (see the schema). */
export interface LightSet {
  schema?: string;
  seq: number;
  frame?: number;
  t_capture_ns: number;
  t_emit_ns: number;
  lights: WireLight[];
  /** L2 radiance SH of the map, 27 floats, [c0.r, c0.g, c0.b, c1.r, …], three.js's basis order. */
  sh9?: number[];
  /** sh9 minus the shadowed lights' projections (with `shadowed=K`). */
  sh9_unshadowed?: number[];
  [field: string]: unknown;
}

/** A light as DirectionalLight parameters: color × intensity = irradiance, direction = to_light. */
export interface DirectionalParams {
  id: number;
  direction: Vec3;
  color: Vec3;
  intensity: number;
  angularRadius: number;
  /** Where the shadow map is drawn from: `extent.core_to_light` within `ONE_MAP_CORE_DEG[0]` of `direction`, `direction` from `ONE_MAP_CORE_DEG[1]`, turned part way between. */
  shadowDirection: Vec3;
}

export interface Plan {
  shadowed: DirectionalParams[];
  /** The LightProbe's coefficients (intensity 1), 27 floats in the wire's layout. */
  sh: Float64Array;
  /** Whether the daemon marked the shadowed lights (else they were chosen here). */
  fromServer: boolean;
}

export declare function luminance(rgb: ArrayLike<number>): number;
export declare function shBasis(x: number, y: number, z: number, out?: number[]): number[];
export declare function directionalParams(light: WireLight): DirectionalParams;
export declare function chooseShadowed(
  set: LightSet,
  k: number,
  previousIds?: Set<number>,
  stickiness?: number,
): { lights: WireLight[]; fromServer: boolean };
export declare function remainderSh(set: LightSet, shadowedLights: WireLight[]): Float64Array;
export declare function planSet(set: LightSet, k: number, previousIds?: Set<number>): Plan;
export declare function shadowRadius(
  angularRadius: number,
  o: { mapSize: number; frustumWidth: number; occluderDistance: number; maxRadius?: number },
): number;
export declare function setAge(
  set: Pick<LightSet, "t_capture_ns" | "t_emit_ns">,
  arrivalMs: number,
  offsetMs?: number,
): { ageMs: number; offsetMs: number };

export interface VemlightLightsOptions {
  /** `ws://host:7878/v1/stream` (http(s) URLs are turned into ws(s)); none: call applySet yourself. */
  url?: string | null;
  /** The daemon's token, sent as `access_token`. */
  token?: string | null;
  /** Most lights per set (`lights=N`). Default 16. */
  lights?: number;
  /** Shadow-casting lights (`shadowed=K`), the size of the DirectionalLight pool. Default 4. */
  shadowed?: number;
  /** Relative diffuse error the daemon may meet with fewer lights (`max_error=E`). */
  maxError?: number | null;
  /** The box the shadow cameras cover: the casters and the ground they shadow. */
  target?: Box3 | null;
  /** Shadow map side in texels. Default 1024. */
  mapSize?: number;
  /** Largest PCF radius in texels. Default 8. */
  maxRadius?: number;
  /** Occluder-to-receiver distance for the penumbra; default half the target box's height. */
  occluderDistance?: number | null;
  /** Time constant of the smoothing between sets, seconds (0: none). Default 0.1. */
  smoothingS?: number;
  /** Sets older than this (ms since capture, clock skew removed) are dropped. Default 1000. */
  maxAgeMs?: number;
  /** Reconnect backoff: first delay and cap, ms (doubling, ±25 % jitter). Defaults 250, 10000. */
  backoffMinMs?: number;
  backoffMaxMs?: number;
  shadowBias?: number;
  shadowNormalBias?: number;
  /** A WebSocket implementation (Node's `ws`, a test double). Default globalThis.WebSocket. */
  WebSocket?: new (url: string, protocol: string) => WebSocket;
  onSet?: (set: LightSet, plan: Plan) => void;
  onStatus?: (text: string, stats: VemlightStats) => void;
}

export interface VemlightStats {
  connected: boolean;
  /** "server": the daemon marks the shadowed lights; "client": chosen here; "legacy": the daemon refused `shadowed`. */
  wire: "unknown" | "server" | "client" | "legacy";
  seq: number | null;
  received: number;
  applied: number;
  droppedOld: number;
  droppedOutOfOrder: number;
  reconnects: number;
  lastError: string | null;
}

export declare class VemlightLights {
  constructor(scene: Object3D, options?: VemlightLightsOptions);
  readonly options: Required<VemlightLightsOptions>;
  /** Holds the pool and the probe; added to the scene given. */
  readonly group: Group;
  readonly probe: LightProbe;
  readonly stats: VemlightStats;
  readonly lastSet: LightSet | null;
  readonly lastPlan: Plan | undefined;
  /** The pool's lights that hold a shadowed light, with its id. */
  readonly shadowedLights: { id: number; light: DirectionalLight }[];
  setBudget(budget: { lights?: number; shadowed?: number; maxError?: number | null }): void;
  streamUrl(): string;
  connect(): void;
  /** Applies a set (what the stream does for each message); false when dropped as old or out of order. */
  applySet(set: LightSet, arrivalMs?: number): boolean;
  /** Advances smoothing by dt seconds and fits the shadow cameras; call once a frame. */
  update(dt?: number): void;
  dispose(): void;
}
