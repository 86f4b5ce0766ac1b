// Module resolve hook (see register.mjs): "three" → ../vendor/three.module.min.js.
const vendored = new URL("../vendor/three.module.min.js", import.meta.url).href;

export async function resolve(specifier, context, next) {
  if (specifier === "three") return { url: vendored, format: "module", shortCircuit: true };
  return next(specifier, context);
}
