//! Example loader: `Example::load` (the path the CLI uses) must return Ok or a one-line
//! Err for any file content; an accepted example is at least 8x8 with linear values in
//! 0..1. The input is written to a per-process scratch file, because the loader reads
//! files (it decides the format from the content, not the name).
#![no_main]

use libfuzzer_sys::fuzz_target;
use std::path::PathBuf;
use std::sync::OnceLock;
use surfsynth::example::Example;

fn scratch() -> &'static PathBuf {
    static P: OnceLock<PathBuf> = OnceLock::new();
    P.get_or_init(|| std::env::temp_dir().join(format!("surfsynth-fuzz-{}.png", std::process::id())))
}

fuzz_target!(|data: &[u8]| {
    let path = scratch();
    std::fs::write(path, data).expect("write scratch file");
    match Example::load(path) {
        Err(e) => {
            let msg = e.to_string();
            assert!(!msg.contains('\n'), "one line: {msg:?}");
        }
        Ok(e) => {
            let px = e.width * e.height;
            assert!(e.width >= 8 && e.height >= 8);
            assert_eq!(e.rgb.len(), px);
            let unit = |v: f32| (0.0..=1.0).contains(&v);
            assert!(e.rgb.iter().flatten().all(|&v| unit(v)));
            if let Some(a) = &e.alpha {
                assert_eq!(a.len(), px);
                assert!(a.iter().all(|&v| unit(v)));
            }
        }
    }
});
