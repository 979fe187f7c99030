// Validate glTF/GLB files with the Khronos glTF Validator; print one JSON report per file.
// Usage: node tools/gltf-validator/validate.mjs FILE...   Exit code 1 when any file has errors.
import { readFile } from "node:fs/promises";
import validator from "gltf-validator";

let failed = false;
for (const path of process.argv.slice(2)) {
  const report = await validator.validateBytes(new Uint8Array(await readFile(path)), {
    uri: path,
    maxIssues: 50,
  });
  const { numErrors, numWarnings, numInfos, messages } = report.issues;
  console.log(JSON.stringify({ path, numErrors, numWarnings, numInfos, messages: messages.slice(0, 10) }));
  failed ||= numErrors > 0;
}
process.exit(failed ? 1 : 0);
