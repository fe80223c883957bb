//! The engine runs inside marsd's real-time process: it links the checkpoint format and its kernels, never the
//! trainer, plotting, the command line, datasets or candle. Checked on the resolved dependency tree, so a
//! dependency added back by anyone (directly or through another crate) turns this red.

use std::process::Command;

#[test]
fn the_engine_links_no_trainer_plotting_cli_or_dataset_crate() {
    let out = Command::new(env!("CARGO"))
        .args(["tree", "-p", "mars-engine", "-e", "normal", "--prefix", "none", "--locked", "--offline"])
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .expect("cargo runs");
    let tree = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "cargo tree failed: {}", String::from_utf8_lossy(&out.stderr));
    assert!(tree.contains("mars-policy-format"), "the tree is not the engine's:\n{tree}");
    let forbidden = [
        "candle-core",
        "candle-nn",
        "plotters",
        "clap",
        "indicatif",
        "mimalloc",
        "mars-policy ",
        "mars-tasks",
        "mars-lerobot",
    ];
    let found: Vec<&str> = tree.lines().filter(|line| forbidden.iter().any(|f| line.starts_with(f))).collect();
    assert!(found.is_empty(), "the engine's normal dependencies include {found:?}");
    println!(
        "{} crates in the engine's normal dependency tree",
        tree.lines().collect::<std::collections::BTreeSet<_>>().len()
    );
}
