//! `flowfilter synth` writes a capture that `flowfilter inspect` accepts; bad options fail clearly.

use std::process::Command;

fn flowfilter(args: &[&str]) -> (bool, String, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_flowfilter")).args(args).output().unwrap();
    (out.status.success(), String::from_utf8_lossy(&out.stdout).into(), String::from_utf8_lossy(&out.stderr).into())
}

#[test]
fn synth_then_inspect() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("can");
    let sheet = tmp.path().join("sheet.png");
    let (ok, stdout, stderr) = flowfilter(&[
        "synth",
        "--procedural",
        "can",
        "--out",
        out.to_str().unwrap(),
        "--cameras",
        "NP2,NP5",
        "--angles",
        "0:6:3",
        "--noise",
        "none",
        "--seed",
        "4",
        "--contact-sheet",
        sheet.to_str().unwrap(),
    ]);
    assert!(ok, "{stderr}");
    assert!(stdout.contains("wrote 6 frames (2 camera(s) x 3 angle(s))"), "{stdout}");
    assert!(image::open(&sheet).is_ok());
    let (ok, stdout, stderr) = flowfilter(&["inspect", out.to_str().unwrap()]);
    assert!(ok, "{stderr}");
    assert!(stdout.contains("NP2:     3 frames, colour 1280x1024, depth 640x480"), "{stdout}");
    assert!(stdout.contains("calibration: 5 Carmine sensor(s)"), "{stdout}");
}

#[test]
fn synth_rejects_bad_options() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("x");
    let o = out.to_str().unwrap();
    for (args, needle) in [
        (vec!["synth", "--procedural", "teapot", "--out", o], "invalid value 'teapot' for '--procedural <PROCEDURAL>'"),
        (vec!["synth", "--procedural", "box", "--out", o, "--angles", "0:357:0"], "step must be > 0"),
        (vec!["synth", "--procedural", "box", "--out", o, "--angles", "10:400:3"], "not in 0..360"),
        (vec!["synth", "--procedural", "box", "--out", o, "--cameras", "NP7"], "'NP7' is not a sensor name"),
        (vec!["synth", "--procedural", "box", "--out", o, "--noise", "/no/profile.toml"], "/no/profile.toml"),
        (vec!["synth", "--mesh", "/no/mesh.obj", "--out", o], "/no/mesh.obj"),
    ] {
        let (ok, _, stderr) = flowfilter(&args);
        assert!(!ok, "{args:?} should fail");
        assert!(stderr.contains(needle), "{args:?}: '{needle}' not in {stderr}");
    }
    let (ok, _, stderr) = flowfilter(&["synth", "--out", o]);
    assert!(!ok && stderr.contains("--mesh"), "{stderr}");
}
