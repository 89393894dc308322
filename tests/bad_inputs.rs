//! Bad input to `surfsynth bake`: one test per class. Each must fail with a non-zero exit
//! code, exactly one line on stderr that names the file (when there is one) and the
//! problem, no panic text, and nothing written to `--out`.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

mod common;
use common::shared;

fn cube() -> PathBuf {
    shared().join("data/opensubdiv-reference/catmark_cube.obj")
}

fn run<S: AsRef<std::ffi::OsStr>>(args: &[S]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_surfsynth"))
        .args(args)
        .output()
        .unwrap()
}

/// Files (recursively) under `dir`, if it exists.
fn files_in(dir: &Path) -> Vec<PathBuf> {
    let mut v = Vec::new();
    if let Ok(rd) = std::fs::read_dir(dir) {
        for e in rd {
            let p = e.unwrap().path();
            if p.is_dir() {
                v.extend(files_in(&p));
            } else {
                v.push(p);
            }
        }
    }
    v
}

/// Checks the error contract and returns the message.
fn assert_clean_failure(o: &Output, out: &Path, names: Option<&Path>, problem: &[&str]) -> String {
    let stderr = String::from_utf8_lossy(&o.stderr).into_owned();
    assert!(!o.status.success(), "should fail; stderr: {stderr}");
    let code = o.status.code().unwrap();
    assert!(code == 1 || code == 2, "exit code {code}: {stderr}");
    assert!(!stderr.contains("panicked"), "panic text: {stderr}");
    assert!(!stderr.contains("RUST_BACKTRACE"), "panic text: {stderr}");
    let line = stderr.strip_suffix('\n').unwrap_or(&stderr);
    assert!(
        !line.is_empty() && !line.contains('\n'),
        "exactly one line: {stderr:?}"
    );
    assert!(line.starts_with("error: "), "{line}");
    if let Some(p) = names {
        assert!(
            line.contains(&p.display().to_string()),
            "names the file: {line}"
        );
    }
    let lower = line.to_lowercase();
    for w in problem {
        assert!(lower.contains(&w.to_lowercase()), "mentions '{w}': {line}");
    }
    assert!(
        files_in(out).is_empty(),
        "--out holds files: {:?}",
        files_in(out)
    );
    assert!(o.stdout.is_empty(), "no summary on failure");
    line.to_string()
}

/// Writes `obj` to `dir/name`, bakes it at N = 4 into `dir/out`: the run, the mesh, the
/// output directory.
fn bake_obj(dir: &Path, name: &str, obj: &str) -> (Output, PathBuf, PathBuf) {
    let mesh = dir.join(name);
    std::fs::write(&mesh, obj).unwrap();
    let out = dir.join("out");
    let o = run(&[
        "bake".as_ref(),
        "--mesh".as_ref(),
        mesh.as_os_str(),
        "--resolution".as_ref(),
        "4".as_ref(),
        "--out".as_ref(),
        out.as_os_str(),
    ]);
    (o, mesh, out)
}

/// Writes `obj` to a temporary file, bakes it, and checks the failure.
fn bad_obj(obj: &str, problem: &[&str]) -> String {
    let dir = tempfile::tempdir().unwrap();
    let (o, mesh, out) = bake_obj(dir.path(), "bad.obj", obj);
    assert_clean_failure(&o, &out, Some(&mesh), problem)
}

const SQUARE_VERTS: &str = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\n";

#[test]
fn missing_mesh_file() {
    let dir = tempfile::tempdir().unwrap();
    let mesh = dir.path().join("nope.obj");
    let out = dir.path().join("out");
    let o = run(&[
        "bake".as_ref(),
        "--mesh".as_ref(),
        mesh.as_os_str(),
        "--out".as_ref(),
        out.as_os_str(),
    ]);
    assert_clean_failure(&o, &out, Some(&mesh), &["cannot read", "no such file"]);
    assert!(!out.exists(), "--out is not created for bad input");
}

#[test]
fn zero_byte_obj() {
    bad_obj("", &["zero faces"]);
}

#[test]
fn obj_with_zero_faces() {
    bad_obj(
        &format!("# only vertices\n{SQUARE_VERTS}vt 0 0\n"),
        &["zero faces"],
    );
}

/// Non-manifold meshes are not bad input: they are cut apart and made sharp as OpenSubdiv
/// makes them (subdiv's `nonmanifold`; the surface checked against OpenSubdiv in
/// `subdiv/tests/opensubdiv_creases.rs`), with one note naming the file.
#[test]
fn non_manifold_meshes_are_baked_with_a_note() {
    let edge = format!(
        "{SQUARE_VERTS}v 2 0 0\nv 2 1 0\nv 1 0 1\nv 1 1 1\nf 1 2 3 4\nf 2 5 6 3\nf 2 3 8 7\n"
    );
    let bow_tie = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv -1 0 0\nv 0 -1 0\nf 1 2 3\nf 1 4 5\n".to_string();
    for (obj, what) in [
        (edge, "1 non-manifold edge and 2 non-manifold vertices"),
        (bow_tie, "1 non-manifold vertex"),
    ] {
        let dir = tempfile::tempdir().unwrap();
        let (o, mesh, out) = bake_obj(dir.path(), "nm.obj", &obj);
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(o.status.success(), "{err}");
        assert!(out.join("geometry.exr").is_file());
        let note = format!(
            "{}: {what} cut apart and made sharp, as OpenSubdiv treats non-manifold input",
            mesh.display()
        );
        assert!(err.contains(&note), "{err}");
    }
}

#[test]
fn inconsistent_orientation() {
    // Both quads run along edge 2 -> 3 in the same direction.
    let obj = format!("{SQUARE_VERTS}v 2 0 0\nv 2 1 0\nf 1 2 3 4\nf 2 3 6 5\n");
    bad_obj(&obj, &["inconsistent", "orientation"]);
}

#[test]
fn face_with_repeated_vertex() {
    bad_obj(&format!("{SQUARE_VERTS}f 1 2 2 3\n"), &["repeats vertex"]);
}

#[test]
fn face_with_two_vertices() {
    bad_obj(
        &format!("{SQUARE_VERTS}f 1 2\n"),
        &["face 1 ", "at least 3"],
    );
}

#[test]
fn out_of_range_index() {
    bad_obj(
        &format!("{SQUARE_VERTS}f 1 2 3 9\n"),
        &["face 1 refers to vertex 9", "only 4 vertices"],
    );
}

#[test]
fn nan_coordinate() {
    bad_obj(
        "v 0 0 0\nv 1 nan 0\nv 1 1 0\nv 0 1 0\nf 1 2 3 4\n",
        &["non-finite"],
    );
}

#[test]
fn infinite_coordinate() {
    bad_obj(
        "v 0 0 0\nv 1 0 0\nv inf 1 0\nv 0 1 0\nf 1 2 3 4\n",
        &["non-finite"],
    );
}

#[test]
fn text_that_is_not_obj() {
    bad_obj("v 0 0 zero\nf 1 2 3\n", &["coordinate"]);
}

fn bad_args(extra: &[&str], problem: &[&str]) {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    let mut args: Vec<std::ffi::OsString> = vec![
        "bake".into(),
        "--mesh".into(),
        cube().into(),
        "--out".into(),
        out.clone().into(),
    ];
    args.extend(extra.iter().map(|s| s.into()));
    let o = run(&args);
    assert_clean_failure(&o, &out, None, problem);
    assert!(!out.exists(), "--out is not created for bad arguments");
}

#[test]
fn resolution_zero() {
    bad_args(&["--resolution", "0"], &["--resolution", "at least 1"]);
}

#[test]
fn absurd_resolution() {
    bad_args(
        &["--resolution", "100000"],
        &["--resolution", "too large", "8192"],
    );
}

#[test]
fn resolution_not_a_number() {
    bad_args(&["--resolution", "big"], &["--resolution", "'big'"]);
}

#[test]
fn unknown_flag() {
    bad_args(&["--colour", "red"], &["--colour"]);
}

#[test]
fn zero_threads() {
    bad_args(&["--threads", "0"], &["--threads", "between 1 and"]);
}

#[test]
fn out_is_an_existing_regular_file() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("taken");
    std::fs::write(&out, b"keep me").unwrap();
    let o = run(&[
        "bake".as_ref(),
        "--mesh".as_ref(),
        cube().as_os_str(),
        "--out".as_ref(),
        out.as_os_str(),
    ]);
    let stderr = String::from_utf8_lossy(&o.stderr).into_owned();
    assert!(!o.status.success());
    let line = stderr.trim_end();
    assert!(
        !line.contains('\n') && line.starts_with("error: "),
        "{stderr:?}"
    );
    assert!(line.contains(&out.display().to_string()), "{line}");
    assert!(line.contains("must be a directory"), "{line}");
    assert!(!stderr.contains("panicked"));
    assert_eq!(
        std::fs::read(&out).unwrap(),
        b"keep me",
        "the file is untouched"
    );
    let siblings: Vec<_> = std::fs::read_dir(dir.path()).unwrap().collect();
    assert_eq!(siblings.len(), 1, "no temporary files beside it");
}

#[test]
fn out_below_a_regular_file() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("taken");
    std::fs::write(&file, b"").unwrap();
    let out = file.join("sub");
    let o = run(&[
        "bake".as_ref(),
        "--mesh".as_ref(),
        cube().as_os_str(),
        "--out".as_ref(),
        out.as_os_str(),
    ]);
    assert_clean_failure(&o, &out, Some(&out), &["output directory"]);
}

#[test]
fn eval_and_render_of_a_directory_without_results_fail_cleanly() {
    let dir = tempfile::tempdir().unwrap();
    for cmd in ["eval", "render"] {
        let o = run(&[cmd.as_ref(), dir.path().as_os_str()]);
        assert_clean_failure(&o, dir.path(), Some(dir.path()), &[]);
    }
}

#[test]
fn internal_errors_print_one_line_and_exit_101() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    let o = Command::new(env!("CARGO_BIN_EXE_surfsynth"))
        .env("SURFSYNTH_INJECT_PANIC", "1")
        .env("RUST_BACKTRACE", "1")
        .arg("bake")
        .arg("--mesh")
        .arg(cube())
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(101));
    let stderr = String::from_utf8_lossy(&o.stderr);
    let line = stderr.trim_end();
    assert!(!line.contains('\n'), "one line: {stderr:?}");
    assert!(
        line.starts_with("error: internal error: injected panic"),
        "{line}"
    );
    assert!(
        !stderr.contains("panicked") && !stderr.contains("backtrace"),
        "{stderr}"
    );
}
