//! `cargo xtask publish-check`: every library crate packages (and its package builds on its
//! own, in dependency order), each package carries its README, licence files and the files it
//! embeds, and a scratch crate outside the workspace that depends on `flowfilter-registration`
//! by path and version builds and runs that crate's README example.

use crate::repo_root;
use anyhow::{Context, bail};
use clap::Args;
use std::process::Command;

/// Arguments of `publish-check`.
#[derive(Args)]
pub struct PublishCheckArgs {
    /// Skip building each package from its tarball (`cargo package --no-verify`).
    #[arg(long)]
    pub no_verify: bool,
}

/// The crates that are published, in dependency order.
pub const PUBLISHED: [&str; 13] = [
    "flowfilter-geometry",
    "flowfilter-camera",
    "flowfilter-eval",
    "flowfilter-bigbird",
    "flowfilter-synth",
    "flowfilter-depth",
    "flowfilter-flow",
    "flowfilter-registration",
    "flowfilter-photometric",
    "flowfilter-pipeline",
    "flowfilter-rerun",
    "flowfilter-track",
    "flowfilter",
];

/// Files every package must carry, and the extra files some embed.
fn required_files(krate: &str) -> Vec<&'static str> {
    let mut files = vec!["Cargo.toml", "README.md", "LICENSE-MIT", "LICENSE-APACHE"];
    if krate == "flowfilter-flow" {
        files.extend(["models/ffnet.onnx", "models/ffnet.toml", "models/MODEL_CARD.md"]);
    }
    if krate == "flowfilter-synth" {
        files.push("profiles/carmine.toml");
    }
    files
}

fn cargo() -> Command {
    let mut c = Command::new(std::env::var_os("CARGO").unwrap_or_else(|| "cargo".into()));
    c.current_dir(repo_root());
    c
}

fn run_checked(mut c: Command, what: &str) -> anyhow::Result<String> {
    let out = c.output().with_context(|| format!("{what}: cannot start cargo"))?;
    if !out.status.success() {
        bail!("{what} failed:\n{}{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
    }
    Ok(String::from_utf8_lossy(&out.stdout).into_owned())
}

/// Run the check.
pub fn run(args: &PublishCheckArgs) -> anyhow::Result<()> {
    for krate in PUBLISHED {
        let listed = run_checked(
            {
                let mut c = cargo();
                c.args(["package", "--list", "--allow-dirty", "-p", krate]);
                c
            },
            &format!("cargo package --list -p {krate}"),
        )?;
        let files: Vec<&str> = listed.lines().collect();
        for f in required_files(krate) {
            if !files.contains(&f) {
                bail!("{krate}: the package lacks {f} (it holds: {})", files.join(", "));
            }
        }
        tracing::info!(krate, files = files.len(), "package contents checked");
    }
    let mut package = cargo();
    package.args(["package", "--workspace", "--exclude", "xtask", "--allow-dirty"]);
    if args.no_verify {
        package.arg("--no-verify");
    }
    // The verification builds need no debug info (disk and time on CI machines).
    package.env("CARGO_PROFILE_DEV_DEBUG", "false");
    tracing::info!(verify = !args.no_verify, "cargo package --workspace");
    run_checked(package, "cargo package --workspace")?;
    println!("publish-check: {} crates package{}", PUBLISHED.len(), if args.no_verify { "" } else { " and build" });
    let output = scratch_crate_runs_the_readme_example()?;
    println!("publish-check: a crate outside the workspace ran flowfilter-registration's README example:\n{output}");
    Ok(())
}

/// The first Rust code block of a README, as the body of a function (doctest `# ` lines
/// included).
pub fn readme_example(readme: &str) -> Option<String> {
    let start = readme.find("```rust\n")? + "```rust\n".len();
    let body = &readme[start..];
    let end = body.find("```")?;
    let lines: Vec<&str> =
        body[..end].lines().map(|l| if l == "#" { "" } else { l.strip_prefix("# ").unwrap_or(l) }).collect();
    Some(lines.join("\n"))
}

/// A binary crate in `target/publish-check/scratch` that depends on `flowfilter-registration`
/// by path and version, whose `main` is the README example; built and run, its output returned.
fn scratch_crate_runs_the_readme_example() -> anyhow::Result<String> {
    let root = repo_root().canonicalize().context("repository root")?;
    let crate_dir = root.join("crates/flowfilter-registration");
    let readme = std::fs::read_to_string(crate_dir.join("README.md")).context("flowfilter-registration/README.md")?;
    let body = readme_example(&readme).context("flowfilter-registration/README.md has no ```rust example")?;
    let scratch = root.join("target/publish-check/scratch");
    std::fs::create_dir_all(scratch.join("src"))?;
    std::fs::write(
        scratch.join("Cargo.toml"),
        format!(
            "[package]\nname = \"scratch-user\"\nversion = \"0.0.0\"\nedition = \"2024\"\npublish = false\n\n\
             [dependencies]\nflowfilter-registration = {{ path = {:?}, version = \"0.1\" }}\n\n[workspace]\n",
            crate_dir.display().to_string()
        ),
    )?;
    let indented: String = body.lines().map(|l| format!("        {l}\n")).collect();
    std::fs::write(
        scratch.join("src/main.rs"),
        format!(
            "//! flowfilter-registration's README example, as a user's program.\n\nfn main() {{\n    \
             let run = || -> Result<(), flowfilter_registration::RegistrationError> {{\n{indented}    }};\n    \
             if let Err(e) = run() {{\n        eprintln!(\"error: {{e}}\");\n        std::process::exit(1);\n    }}\n}}\n"
        ),
    )?;
    // The workspace's lock file pins the same dependency versions (no index query needed).
    std::fs::copy(root.join("Cargo.lock"), scratch.join("Cargo.lock"))?;
    let mut c = Command::new(std::env::var_os("CARGO").unwrap_or_else(|| "cargo".into()));
    c.current_dir(&scratch)
        .args(["run", "--quiet", "--offline"])
        .env("CARGO_TARGET_DIR", root.join("target/publish-check/target"))
        .env("CARGO_PROFILE_DEV_DEBUG", "false");
    run_checked(c, "the scratch crate (cargo run in target/publish-check/scratch)")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn readme_examples_keep_their_hidden_lines() {
        let readme = "# x\n\n```rust\nlet a = 1;\n# let b = a;\n#\n# Ok::<(), E>(())\n```\nmore\n```rust\nother\n```\n";
        assert_eq!(readme_example(readme).unwrap(), "let a = 1;\nlet b = a;\n\nOk::<(), E>(())");
        assert_eq!(readme_example("no code"), None);
    }

    #[test]
    fn every_published_crate_is_a_workspace_member_with_a_readme() {
        for krate in PUBLISHED {
            let dir = repo_root().join("crates").join(krate);
            let manifest: toml::Table =
                toml::from_str(&std::fs::read_to_string(dir.join("Cargo.toml")).unwrap()).unwrap();
            let package = manifest["package"].as_table().unwrap();
            assert_eq!(package["name"].as_str(), Some(krate));
            for key in ["description", "readme", "keywords", "categories"] {
                assert!(package.contains_key(key), "{krate}: no `{key}`");
            }
            for key in ["license", "repository", "version"] {
                assert!(package.contains_key(key), "{krate}: no `{key}` (inherited from the workspace)");
            }
            for f in required_files(krate) {
                assert!(dir.join(f).is_file(), "{krate}: {f} missing");
            }
        }
    }
}
