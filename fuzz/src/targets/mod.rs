//! The targets: each a decoder of the product fed as the product feeds it, then made to use what it accepted.
//! Every target is a set of seed bundles (one file each, or several files a decoder reads together: a checkpoint's
//! two, a dataset's three) and a decode function; a case mutates one file of one bundle.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use rand::Rng;
use rand::rngs::StdRng;

use crate::mutate::mutate;
use crate::runner::Target;

mod checkpoint;
mod configs;
mod lerobot;
mod remote;
mod ros2;
mod wire;

/// Every target, in the order `all` runs them.
pub fn all() -> Vec<Arc<dyn Target>> {
    vec![
        lerobot::info(),
        lerobot::episodes(),
        lerobot::dataset(),
        checkpoint::policy_json(),
        checkpoint::policy_toml(),
        checkpoint::checkpoint(),
        configs::marsd_config(),
        configs::marsd_task(),
        configs::hal_profile(),
        wire::frames(),
        remote::messages(),
        remote::live_frames(),
        ros2::cdr(),
        ros2::jpeg(),
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

/// The decode function of a [`Bundles`] target: the bundle's index, the mutated file's index and its bytes; true
/// when the decoder accepted the input.
pub(crate) type Decode = Box<dyn Fn(usize, usize, &[u8]) -> bool + Send + Sync>;

/// A target: seed bundles, which of a bundle's files are text (mutated token-wise too), and how they are decoded.
/// An input is `[bundle, file]` then the mutated file's bytes.
pub(crate) struct Bundles {
    pub name: &'static str,
    pub bundles: Vec<Vec<Vec<u8>>>,
    pub text: fn(usize) -> bool,
    pub decode: Decode,
}

impl Bundles {
    /// A target of single files (one bundle each).
    pub fn of_files(
        name: &'static str,
        files: Vec<Vec<u8>>,
        text: bool,
        decode: impl Fn(usize, &[u8]) -> bool + Send + Sync + 'static,
    ) -> Arc<dyn Target> {
        let text: fn(usize) -> bool = if text { |_| true } else { |_| false };
        let decode: Decode = Box::new(move |b, _, bytes| decode(b, bytes));
        Arc::new(Self { name, bundles: files.into_iter().map(|f| vec![f]).collect(), text, decode })
    }
}

/// UTF-8 text, as the product's `read_to_string` takes it (other bytes are an I/O error there).
pub(crate) fn text(bytes: &[u8]) -> Option<&str> {
    std::str::from_utf8(bytes).ok()
}

impl Target for Bundles {
    fn name(&self) -> &'static str {
        self.name
    }

    fn generate(&self, rng: &mut StdRng) -> Vec<u8> {
        let b = rng.random_range(0..self.bundles.len());
        let f = rng.random_range(0..self.bundles[b].len());
        let others: Vec<&[u8]> = self.bundles.iter().filter_map(|x| x.get(f)).map(Vec::as_slice).collect();
        let mut input = vec![b as u8, f as u8];
        input.extend_from_slice(&mutate(rng, &self.bundles[b][f], &others, (self.text)(f)));
        input
    }

    fn seeds(&self) -> Vec<Vec<u8>> {
        let mut out = Vec::new();
        for (b, files) in self.bundles.iter().enumerate() {
            for (f, bytes) in files.iter().enumerate() {
                out.push([&[b as u8, f as u8][..], bytes].concat());
            }
        }
        out
    }

    fn run(&self, input: &[u8]) -> bool {
        match input {
            [b, f, bytes @ ..] => {
                let b = *b as usize % self.bundles.len();
                (self.decode)(b, *f as usize % self.bundles[b].len(), bytes)
            }
            _ => false,
        }
    }
}
