// `node --import ./test/register.mjs --test`: resolves the bare specifier "three" to the vendored
// build (vendor/three.module.min.js), the very file the daemon serves to the demo page, so the
// tests need neither npm nor node_modules.
import { register } from "node:module";

register("./resolve-three.mjs", import.meta.url);
