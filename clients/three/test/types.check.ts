// Compiled by `npm run typecheck` only: the README's usage against the declarations.
import { Box3, PerspectiveCamera, Scene, Vector3, WebGLRenderer } from "three";
import { VemlightLights, planSet, type LightSet } from "../vemlight-three.js";

const scene = new Scene();
const renderer = new WebGLRenderer();
renderer.shadowMap.enabled = true;
const camera = new PerspectiveCamera();
const lights = new VemlightLights(scene, {
  url: "ws://127.0.0.1:7878/v1/stream",
  shadowed: 4,
  target: new Box3(new Vector3(-2, 0, -2), new Vector3(2, 2, 2)),
});
renderer.setAnimationLoop(() => {
  lights.update(1 / 60);
  renderer.render(scene, camera);
});
const set: LightSet = { seq: 1, t_capture_ns: 0, t_emit_ns: 0, lights: [] };
const k: number = planSet(set, 2).shadowed.length + lights.shadowedLights.length;
lights.setBudget({ shadowed: k });
lights.dispose();
