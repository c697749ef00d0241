// Validates GLB files with the Khronos glTF validator (npm gltf-validator); prints one line per
// file with issues and a summary `validated N files: E errors, W warnings`. Exit code 1 on errors.
// Used by tests/export_formats.rs: node tools/web/validate_glb.mjs a.glb b.glb ...
import { readFileSync } from 'node:fs';
import { createRequire } from 'node:module';
const require = createRequire(import.meta.url);
const validator = require('gltf-validator');

let errors = 0, warnings = 0;
const files = process.argv.slice(2);
for (const f of files) {
  const report = await validator.validateBytes(new Uint8Array(readFileSync(f)), { uri: f });
  errors += report.issues.numErrors;
  warnings += report.issues.numWarnings;
  if (report.issues.numErrors + report.issues.numWarnings > 0) {
    console.log(`${f}: ${report.issues.numErrors} errors, ${report.issues.numWarnings} warnings`);
    for (const m of report.issues.messages.slice(0, 5)) console.log(`  ${m.severity} ${m.code} ${m.pointer ?? ''}: ${m.message}`);
  }
}
console.log(`validated ${files.length} files: ${errors} errors, ${warnings} warnings`);
process.exit(errors > 0 ? 1 : 0);
