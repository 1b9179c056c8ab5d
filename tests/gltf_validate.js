// Validate glTF/GLB files with the Khronos glTF-Validator (npm `gltf-validator`) and print one JSON report per file.
//   node gltf_validate.js VALIDATOR_DIR FILE [FILE ...]
// The validator does not know KHR_gaussian_splatting yet: it reports the extension's attribute semantics as
// MESH_PRIMITIVE_INVALID_ATTRIBUTE errors, so that one code is lowered to information (its severity 2); every other
// check keeps its severity.
const fs = require("fs");
const path = require("path");
const [dir, ...files] = process.argv.slice(2);
const validator = require(path.join(dir, "node_modules", "gltf-validator"));
(async () => {
  const reports = [];
  for (const file of files) {
    const report = await validator.validateBytes(new Uint8Array(fs.readFileSync(file)), {
      uri: file, format: file.endsWith(".glb") ? "glb" : "gltf", maxIssues: 0,
      severityOverrides: { MESH_PRIMITIVE_INVALID_ATTRIBUTE: 2 },
    });
    reports.push({ file, issues: report.issues, info: report.info });
  }
  console.log(JSON.stringify(reports));
})().catch((e) => { console.error(String(e)); process.exit(1); });
