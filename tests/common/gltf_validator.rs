//! The Khronos glTF validator (npm package `gltf-validator`), installed once with npm into
//! `target/tmp/gltf-validator` and run with node. Where node or npm is missing, or the
//! package cannot be installed, [`validate`] says why and returns `None`.
#![allow(dead_code)]

use serde_json::Value;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::OnceLock;

/// Pinned: the version the docs quote (docs/formats.md).
pub const VERSION: &str = "2.0.0-dev.3.10";

const SCRIPT: &str = r#"
const fs = require('fs');
const validator = require(process.argv[2]);
const file = process.argv[3];
validator.validateBytes(new Uint8Array(fs.readFileSync(file)), { uri: file, maxIssues: 1000 })
  .then((r) => console.log(JSON.stringify(r)))
  .catch((e) => { console.error('validator failed: ' + e); process.exit(1); });
"#;

fn install() -> Result<PathBuf, String> {
    for tool in ["node", "npm"] {
        if Command::new(tool).arg("--version").output().is_err() {
            return Err(format!("{tool} not found"));
        }
    }
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join(format!("gltf-validator-{VERSION}"));
    let module = dir.join("node_modules/gltf-validator");
    if !module.join("package.json").exists() {
        std::fs::create_dir_all(&dir).map_err(|e| e.to_string())?;
        let out = Command::new("npm")
            .args([
                "install",
                "--no-audit",
                "--no-fund",
                "--no-save",
                "--prefix",
            ])
            .arg(&dir)
            .arg(format!("gltf-validator@{VERSION}"))
            .output()
            .map_err(|e| e.to_string())?;
        if !out.status.success() || !module.join("package.json").exists() {
            return Err(format!(
                "npm install gltf-validator failed: {}",
                String::from_utf8_lossy(&out.stderr)
                    .lines()
                    .last()
                    .unwrap_or("")
            ));
        }
    }
    std::fs::write(dir.join("validate.js"), SCRIPT).map_err(|e| e.to_string())?;
    Ok(dir)
}

fn validator() -> Option<&'static PathBuf> {
    static V: OnceLock<Result<PathBuf, String>> = OnceLock::new();
    match V.get_or_init(install) {
        Ok(p) => Some(p),
        Err(why) => {
            eprintln!("skipped the glTF validator: {why}");
            None
        }
    }
}

/// The validator's report on `file` (its JSON), or `None` (with a message) where it
/// cannot run.
pub fn validate(file: &Path) -> Option<Value> {
    let dir = validator()?;
    let out = Command::new("node")
        .arg(dir.join("validate.js"))
        .arg(dir.join("node_modules/gltf-validator"))
        .arg(file)
        .output()
        .expect("run node");
    assert!(
        out.status.success(),
        "validator: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    Some(serde_json::from_slice(&out.stdout).expect("validator JSON"))
}

/// Asserts 0 errors and 0 warnings, printing the report's counts and messages.
pub fn assert_clean(file: &Path) {
    let Some(r) = validate(file) else { return };
    let issues = &r["issues"];
    let messages: Vec<String> = issues["messages"]
        .as_array()
        .unwrap()
        .iter()
        .map(|m| format!("{} {} ({})", m["severity"], m["code"], m["message"]))
        .collect();
    eprintln!(
        "gltf-validator {VERSION} on {}: {} errors, {} warnings, {} infos, {} hints {messages:?}",
        file.display(),
        issues["numErrors"],
        issues["numWarnings"],
        issues["numInfos"],
        issues["numHints"]
    );
    assert_eq!(issues["numErrors"], 0, "{messages:?}");
    assert_eq!(issues["numWarnings"], 0, "{messages:?}");
}
