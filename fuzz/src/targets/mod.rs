//! The targets: each a decoder of the product fed as the product feeds it, then made to use what it accepted.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use rand::Rng;
use rand::rngs::StdRng;

use crate::mutate::mutate;
use crate::runner::Target;

mod checkpoint;
mod configs;
mod lerobot;
mod ros2;
mod wire;

/// Every target, in the order `all` runs them.
pub fn all() -> Vec<Arc<dyn Target>> {
    vec![
        Arc::new(lerobot::Info::new()),
        Arc::new(lerobot::Episodes::new()),
        Arc::new(lerobot::Dataset::new()),
        Arc::new(checkpoint::PolicyJson::new()),
        Arc::new(checkpoint::PolicyToml::new()),
        Arc::new(checkpoint::Checkpoint::new()),
        Arc::new(configs::MarsdConfig::new()),
        Arc::new(configs::MarsdTask::new()),
        Arc::new(configs::HalProfile::new()),
        Arc::new(wire::Frames::new()),
        Arc::new(ros2::Cdr::new()),
        Arc::new(ros2::Jpeg::new()),
    ]
}

/// A file of the repository.
pub(crate) fn repo(path: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..").join(path)
}

pub(crate) fn read(path: &str) -> Vec<u8> {
    let p = repo(path);
    std::fs::read(&p).unwrap_or_else(|e| panic!("seed {}: {e}", p.display()))
}

/// Seeds of one kind, mutated one at a time (spliced with the others).
pub(crate) struct Seeds {
    pub files: Vec<Vec<u8>>,
    pub text: bool,
}

impl Seeds {
    pub fn pick(&self, rng: &mut StdRng) -> (usize, Vec<u8>) {
        let i = rng.random_range(0..self.files.len());
        let others: Vec<&[u8]> = self.files.iter().map(Vec::as_slice).collect();
        (i, mutate(rng, &self.files[i], &others, self.text))
    }
}

/// A multi-file input: which bundle of seeds, which of its files was mutated, and that file's bytes.
pub(crate) fn bundle_input(bundle: usize, file: usize, bytes: &[u8]) -> Vec<u8> {
    let mut v = vec![bundle as u8, file as u8];
    v.extend_from_slice(bytes);
    v
}

/// `(bundle, file, bytes)` of a [`bundle_input`], or `None` for an input too short (a saved one cut by hand).
pub(crate) fn split_bundle(input: &[u8], bundles: usize) -> Option<(usize, usize, &[u8])> {
    match input {
        [b, f, rest @ ..] => Some((*b as usize % bundles, *f as usize, rest)),
        _ => None,
    }
}

/// Every file of every bundle, unmutated, as inputs.
pub(crate) fn bundle_seeds(bundles: &[Vec<Vec<u8>>]) -> Vec<Vec<u8>> {
    bundles
        .iter()
        .enumerate()
        .flat_map(|(b, files)| files.iter().enumerate().map(move |(f, x)| bundle_input(b, f, x)))
        .collect()
}

/// Picks a bundle and one of its files, mutates that file (as text when `text(file)`), and encodes the input.
pub(crate) fn generate_bundle(rng: &mut StdRng, bundles: &[Vec<Vec<u8>>], text: impl Fn(usize) -> bool) -> Vec<u8> {
    let b = rng.random_range(0..bundles.len());
    let f = rng.random_range(0..bundles[b].len());
    let others: Vec<&[u8]> = bundles.iter().filter_map(|x| x.get(f)).map(Vec::as_slice).collect();
    bundle_input(b, f, &mutate(rng, &bundles[b][f], &others, text(f)))
}
