//! `cargo xtask mutate`, briefly: every parser takes seeded random mutations of its formats
//! without a panic (the documented long run is 10 minutes, `--seconds 600`), and a panicking
//! input would fail the run.

use std::process::Command;

#[test]
fn mutated_inputs_of_every_format_cause_no_panic() {
    let out = tempfile::tempdir().unwrap();
    let run = Command::new(env!("CARGO_BIN_EXE_xtask"))
        .args(["mutate", "--seconds", "15", "--seed", "7", "--out", out.path().to_str().unwrap()])
        .output()
        .expect("xtask runs");
    let stdout = String::from_utf8_lossy(&run.stdout);
    assert!(run.status.success(), "{stdout}\n{}", String::from_utf8_lossy(&run.stderr));
    assert!(stdout.contains("no panic"), "{stdout}");
    for target in
        ["ply", "flo", "pbm", "bigbird", "png-frame", "pipeline-toml", "noise-toml", "camera-json", "pairs-csv"]
    {
        let line =
            stdout.lines().find(|l| l.trim_start().starts_with(target)).unwrap_or_else(|| panic!("{target}: {stdout}"));
        let inputs: usize = line.split_whitespace().nth(1).unwrap().parse().unwrap();
        assert!(inputs > 20, "{target}: only {inputs} inputs: {stdout}");
    }
    assert!(!out.path().join("panics").exists());
}
