//! Decoded frames kept on disk, so that reading a dataset again (the next training run) maps the frames instead of
//! decoding the videos again. One file per video file and target size: a header saying what it holds, then every
//! frame's time and its RGB8 bytes, memory-mapped when read.
//!
//! The cache lives outside the dataset (a dataset may be read-only or shared): in `$MARS_CACHE_DIR`, else
//! `$XDG_CACHE_HOME/mars/lerobot`, else `$HOME/.cache/mars/lerobot`, one folder per dataset (named by a hash of its
//! canonical path). Nothing here is ever an error for the read: a cache that cannot be made or written costs a
//! decode and a warning, a cache file that does not match exactly is decoded again and replaced.

use std::fs::File;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::UNIX_EPOCH;

use memmap2::Mmap;

use crate::video::DecodedVideo;

/// Says what follows and at which layout: a file of another version is not read, only replaced.
const MAGIC: &[u8; 8] = b"MARSFRM1";
/// The decoder's output format: frames converted to RGB8, rows packed, channels last.
const FORMAT: &[u8; 8] = b"RGB8\0\0\0\0";
/// Magic, format, length, modification time, height, width, frames, the path's length (then the path).
const FIXED_HEADER: usize = 8 + 8 + 8 + 16 + 4 + 4 + 8 + 4;

/// The cache folder for all datasets: `$MARS_CACHE_DIR`, else `$XDG_CACHE_HOME/mars/lerobot`, else
/// `$HOME/.cache/mars/lerobot` (empty variables count as unset, as the XDG specification says).
pub fn default_dir() -> Option<PathBuf> {
    let var = |name: &str| std::env::var_os(name).filter(|v| !v.is_empty()).map(PathBuf::from);
    var("MARS_CACHE_DIR")
        .or_else(|| var("XDG_CACHE_HOME").map(|d| d.join("mars/lerobot")))
        .or_else(|| var("HOME").map(|d| d.join(".cache/mars/lerobot")))
}

/// FNV-1a, 64 bits: a name that stays the same from build to build (std's hasher promises no such thing).
fn fnv1a(bytes: &[u8]) -> u64 {
    bytes.iter().fold(0xcbf2_9ce4_8422_2325, |h, &b| (h ^ u64::from(b)).wrapping_mul(0x0000_0100_0000_01b3))
}

/// What a cache file must say about the video file it was decoded from: its path in the dataset, its length and
/// modification time (another file put in its place differs in one of them), the frames' size.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Source {
    pub rel_path: Vec<u8>,
    pub len: u64,
    /// Nanoseconds from the Unix epoch (negative before it).
    pub mtime_ns: i128,
    pub height: u32,
    pub width: u32,
}

impl Source {
    /// The facts of `root/rel` as they are now (`None` when the file or its modification time cannot be read:
    /// then the file is decoded, and its error, if any, is the decoder's to say).
    pub fn of(root: &Path, rel: &Path, (height, width): (u32, u32)) -> Option<Self> {
        let meta = std::fs::metadata(root.join(rel)).ok()?;
        let mtime = meta.modified().ok()?;
        let mtime_ns = match mtime.duration_since(UNIX_EPOCH) {
            Ok(d) => d.as_nanos() as i128,
            Err(e) => -(e.duration().as_nanos() as i128),
        };
        Some(Self { rel_path: rel.as_os_str().as_encoded_bytes().to_vec(), len: meta.len(), mtime_ns, height, width })
    }

    fn header(&self, frames: u64) -> Vec<u8> {
        let mut h = Vec::with_capacity(FIXED_HEADER + self.rel_path.len());
        h.extend_from_slice(MAGIC);
        h.extend_from_slice(FORMAT);
        h.extend_from_slice(&self.len.to_le_bytes());
        h.extend_from_slice(&self.mtime_ns.to_le_bytes());
        h.extend_from_slice(&self.height.to_le_bytes());
        h.extend_from_slice(&self.width.to_le_bytes());
        h.extend_from_slice(&frames.to_le_bytes());
        h.extend_from_slice(&(self.rel_path.len() as u32).to_le_bytes());
        h.extend_from_slice(&self.rel_path);
        h
    }

    fn frame_len(&self) -> usize {
        self.height as usize * self.width as usize * 3
    }
}

/// One dataset's folder in the cache.
pub struct FrameCache {
    pub dir: PathBuf,
}

/// A video file's frames from the cache: the times read out, the pixels mapped.
pub struct CachedFrames {
    pub times_s: Vec<f64>,
    map: Mmap,
    rgb_start: usize,
}

impl CachedFrames {
    /// Every frame's bytes, `times_s.len()` frames of `height × width × 3`.
    pub fn rgb(&self) -> &[u8] {
        &self.map[self.rgb_start..]
    }
}

impl FrameCache {
    /// The folder for the dataset at `root` under `cache_dir`, made if missing. An error says why there is no
    /// cache this time (the caller warns and decodes).
    pub fn open(cache_dir: &Path, root: &Path) -> Result<Self, String> {
        let canonical = std::fs::canonicalize(root).map_err(|e| format!("{}: {e}", root.display()))?;
        let name: String = canonical
            .file_name()
            .map(|n| {
                n.to_string_lossy()
                    .chars()
                    .map(|c| if c.is_ascii_alphanumeric() || "._-".contains(c) { c } else { '_' })
                    .collect()
            })
            .unwrap_or_default();
        let dir = cache_dir.join(format!("{name}-{:016x}", fnv1a(canonical.as_os_str().as_encoded_bytes())));
        std::fs::create_dir_all(&dir).map_err(|e| format!("cannot make the cache folder {}: {e}", dir.display()))?;
        Ok(Self { dir })
    }

    /// The cache file for `source` (one per video file and size: a changed file's entry is replaced, not added).
    pub fn path(&self, source: &Source) -> PathBuf {
        self.dir.join(format!("{:016x}-{}x{}-rgb8.frames", fnv1a(&source.rel_path), source.height, source.width))
    }

    /// The frames cached for `source`: `Ok(None)` when there is no cache file, `Err(why)` when there is one that
    /// does not hold exactly these frames (another video, another size or layout, cut short or too long).
    pub fn load(&self, source: &Source) -> Result<Option<CachedFrames>, String> {
        let path = self.path(source);
        let file = match File::open(&path) {
            Ok(f) => f,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
            Err(e) => return Err(format!("{}: {e}", path.display())),
        };
        // Safety: cache files are only ever replaced whole (written under another name, then renamed over), never
        // changed in place, so the file mapped here stays as it is while the map lives.
        let map = unsafe { Mmap::map(&file) }.map_err(|e| format!("{}: cannot map: {e}", path.display()))?;
        let bad = |why: &str| Err(format!("{}: {why}", path.display()));
        let header_len = FIXED_HEADER + source.rel_path.len();
        if map.len() < header_len {
            return bad("shorter than its header");
        }
        let frames_at = FIXED_HEADER - 12;
        let frames = u64::from_le_bytes(map[frames_at..frames_at + 8].try_into().expect("8 bytes"));
        if map[..header_len] != source.header(frames)[..] {
            return bad("its header is not this video file's (changed since, another size or another layout)");
        }
        let expected = usize::try_from(frames)
            .ok()
            .and_then(|n| n.checked_mul(8 + source.frame_len()))
            .and_then(|n| n.checked_add(header_len));
        if expected != Some(map.len()) {
            return bad(&format!("{} bytes, not the {expected:?} its {frames} frames take (cut short?)", map.len()));
        }
        let rgb_start = header_len + 8 * frames as usize;
        let times_s = map[header_len..rgb_start]
            .chunks_exact(8)
            .map(|b| f64::from_le_bytes(b.try_into().expect("8 bytes")))
            .collect();
        Ok(Some(CachedFrames { times_s, map, rgb_start }))
    }

    /// Writes `video`'s frames as `source`'s cache file: under a temporary name first, flushed to disk, then
    /// renamed over the old one, so that a reader never finds a file half-written.
    pub fn store(&self, source: &Source, video: &DecodedVideo) -> Result<(), String> {
        let path = self.path(source);
        let tmp = self.dir.join(format!(
            ".{}.tmp-{}-{}",
            path.file_name().expect("a file name").to_string_lossy(),
            std::process::id(),
            std::time::SystemTime::now().duration_since(UNIX_EPOCH).map_or(0, |d| d.as_nanos())
        ));
        let write = || -> std::io::Result<()> {
            let mut f = File::create(&tmp)?;
            f.write_all(&source.header(video.times_s.len() as u64))?;
            let times: Vec<u8> = video.times_s.iter().flat_map(|t| t.to_le_bytes()).collect();
            f.write_all(&times)?;
            f.write_all(&video.rgb)?;
            f.sync_data()?;
            std::fs::rename(&tmp, &path)
        };
        write().map_err(|e| {
            let _ = std::fs::remove_file(&tmp);
            format!("cannot write the cache file {}: {e}", path.display())
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_hash_is_fnv1a() {
        // The published FNV-1a 64 test vectors.
        assert_eq!(fnv1a(b""), 0xcbf29ce484222325);
        assert_eq!(fnv1a(b"a"), 0xaf63dc4c8601ec8c);
        assert_eq!(fnv1a(b"foobar"), 0x85944171f73967e8);
    }

    #[test]
    fn the_header_has_its_fixed_part_then_the_path() {
        let s = Source { rel_path: b"videos/a.mp4".to_vec(), len: 7, mtime_ns: -3, height: 2, width: 5 };
        let h = s.header(9);
        assert_eq!(h.len(), FIXED_HEADER + 12);
        assert_eq!(&h[FIXED_HEADER - 12..FIXED_HEADER - 4], &9u64.to_le_bytes());
        assert_eq!(&h[FIXED_HEADER..], b"videos/a.mp4");
    }
}
