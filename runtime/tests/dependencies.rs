//! What runs beside the robot links no trainer: marsd links the engine (the checkpoint format and its kernels),
//! never candle, the trainer, or the HIL rig around it, and reads the robot's profile without linking the HAL or a
//! robot driver (the HAL is the robot's process); the engine, inside marsd's real-time process, not even
//! plotting, the command line or datasets. Checked on the resolved dependency trees, so a dependency added back by
//! anyone (directly or through another crate) turns this red.

use std::collections::BTreeSet;
use std::process::Command;

/// The crates (one `name version` line each) in `package`'s normal dependency tree.
fn normal_tree(package: &str) -> BTreeSet<String> {
    let out = Command::new(env!("CARGO"))
        .args(["tree", "-p", package, "-e", "normal", "--prefix", "none", "--locked", "--offline"])
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .expect("cargo runs");
    assert!(out.status.success(), "cargo tree failed: {}", String::from_utf8_lossy(&out.stderr));
    String::from_utf8_lossy(&out.stdout).lines().map(str::to_owned).collect()
}

/// Lines of `tree` naming a crate of `forbidden` (each a name and a space, so `mars-policy ` is not
/// `mars-policy-format`).
fn forbidden_in<'a>(tree: &'a BTreeSet<String>, forbidden: &[&str]) -> Vec<&'a String> {
    tree.iter().filter(|line| forbidden.iter().any(|f| line.starts_with(f))).collect()
}

#[test]
fn marsd_links_no_trainer_candle_hil_rig_or_robot_driver() {
    let tree = normal_tree("mars-runtime");
    assert!(tree.iter().any(|l| l.starts_with("mars-engine ")), "the tree is not marsd's:\n{tree:?}");
    assert!(tree.iter().any(|l| l.starts_with("mars-profile ")), "marsd reads no profile:\n{tree:?}");
    let forbidden = [
        "mars-policy ",
        "candle-core ",
        "candle-nn ",
        "indicatif ",
        "mars-hil ",
        "mars-hal ",
        "franka-rs ",
        "ros2-client ",
        "rustdds ",
    ];
    let found = forbidden_in(&tree, &forbidden);
    assert!(found.is_empty(), "marsd's normal dependencies include {found:?}");
    println!("{} crates in marsd's normal dependency tree", tree.len());
}

#[test]
fn the_engine_links_no_trainer_plotting_cli_or_dataset_crate() {
    let tree = normal_tree("mars-engine");
    assert!(tree.iter().any(|l| l.starts_with("mars-policy-format ")), "the tree is not the engine's:\n{tree:?}");
    let forbidden = [
        "candle-core ",
        "candle-nn ",
        "plotters ",
        "clap ",
        "indicatif ",
        "mimalloc ",
        "mars-policy ",
        "mars-tasks ",
        "mars-lerobot ",
    ];
    let found = forbidden_in(&tree, &forbidden);
    assert!(found.is_empty(), "the engine's normal dependencies include {found:?}");
    println!("{} crates in the engine's normal dependency tree", tree.len());
}
