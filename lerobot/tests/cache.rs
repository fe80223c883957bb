//! The decoded-frame cache: a second read maps the frames the first one decoded and gives the same bytes; a
//! changed video, a damaged cache file or a cache that cannot be written costs a decode, never a wrong pixel or an
//! error. Each test has a cache folder of its own, passed in the options (the environment is the process's, shared
//! by tests running at once); only `the_cache_folder_follows_the_environment` reads the environment.

mod common;

use std::path::{Path, PathBuf};
use std::time::{Duration, SystemTime};

use common::{FRAME, copy, fixture, fixture_episodes, keys, write};
use mars_lerobot::writer::FileLimits;
use mars_lerobot::{EpisodeFrames, LeRobotDataset, ReadOptions, ReadReport};

const VIDEO: &str = "videos/observation.images.top/chunk-000/file-000.mp4";

fn read(root: &Path, options: &ReadOptions) -> (Vec<EpisodeFrames>, ReadReport) {
    LeRobotDataset::open(root).unwrap().read_with(&keys(), (64, 64), options).unwrap()
}

/// (decoded files, cached files, cache warnings) of a read.
fn counts(r: &ReadReport) -> (usize, usize, usize) {
    (r.decoded_files, r.cached_files, r.cache_warnings.len())
}

/// Every cache file under `dir`.
fn cache_files(dir: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    for d in std::fs::read_dir(dir).unwrap() {
        for f in std::fs::read_dir(d.unwrap().path()).unwrap() {
            out.push(f.unwrap().path());
        }
    }
    out.sort();
    out
}

/// The LeRobot-written fixture read twice (and its frames as a read without the cache gives them): the first read
/// decodes its one file, the second maps it and decodes nothing. Prints both times, the figures a user sees.
#[test]
fn reading_the_fixture_again_takes_its_frames_from_the_cache() {
    let cache = tempfile::tempdir().unwrap();
    let options = ReadOptions::cache_in(cache.path());
    let (uncached, _) = read(&fixture(), &ReadOptions::no_cache());
    let (first, r1) = read(&fixture(), &options);
    let (second, r2) = read(&fixture(), &options);
    assert_eq!(counts(&r1), (1, 0, 0), "{r1:?}");
    assert_eq!((r1.decoded_frames, r1.cached_frames), (180, 0));
    assert_eq!(counts(&r2), (0, 1, 0), "{r2:?}");
    assert_eq!((r2.decoded_frames, r2.cached_frames), (0, 180));
    assert_eq!(first, uncached);
    assert_eq!(second, uncached, "the cache gives the decoder's bytes");
    assert_eq!(cache_files(cache.path()).len(), 1);
    println!(
        "first read: {:.4} s in all; {} frames decoded in {:.4} s ({:.0} frames/s); cache written in {:.4} s",
        r1.total_s,
        r1.decoded_frames,
        r1.decode_s,
        r1.decoded_frames as f64 / r1.decode_s,
        r1.cache_write_s
    );
    println!(
        "second read: {:.4} s in all; {} frames from the cache in {:.4} s ({:.0} frames/s)",
        r2.total_s,
        r2.cached_frames,
        r2.cache_read_s,
        r2.cached_frames as f64 / r2.cache_read_s
    );
}

/// A dataset we wrote, its episodes in three video files: each file decoded once, then each from the cache.
#[test]
fn a_written_dataset_in_several_video_files_reads_from_the_cache() {
    let dir = tempfile::tempdir().unwrap();
    let limits = FileLimits { video_files_size_in_mb: 1e-6, chunks_size: 2, ..FileLimits::default() };
    let episodes: Vec<EpisodeFrames> = fixture_episodes().into_iter().take(3).collect();
    let root = write(&dir.path().join("written"), &episodes, limits);
    let options = ReadOptions::cache_in(&dir.path().join("cache"));
    let (first, r1) = read(&root, &options);
    let (second, r2) = read(&root, &options);
    assert_eq!(counts(&r1), (3, 0, 0), "{r1:?}");
    assert_eq!(counts(&r2), (0, 3, 0), "{r2:?}");
    assert_eq!(second, first);
    assert_eq!(second, read(&root, &ReadOptions::no_cache()).0);
    assert_eq!(cache_files(&dir.path().join("cache")).len(), 3);
    // Another size is another cache file: decoded, then cached as well.
    let ds = LeRobotDataset::open(&root).unwrap();
    let (small, r3) = ds.read_with(&keys(), (32, 48), &options).unwrap();
    assert_eq!(counts(&r3), (3, 0, 0));
    assert!(small.iter().all(|e| e.images[0].len() == e.len * 32 * 48 * 3));
    assert_eq!(ds.read_with(&keys(), (32, 48), &options).unwrap().0, small);
    assert_eq!(cache_files(&dir.path().join("cache")).len(), 6);
}

/// A video file replaced (the same bytes with another modification time; another video of another length) is
/// decoded again: the frames are the new file's, never the cached ones of the file before.
#[test]
fn a_replaced_video_is_decoded_again() {
    let d = copy();
    let cache = tempfile::tempdir().unwrap();
    let options = ReadOptions::cache_in(cache.path());
    let (before, r) = read(d.path(), &options);
    assert_eq!(counts(&r), (1, 0, 0));
    let video = d.path().join(VIDEO);

    let later = SystemTime::now() + Duration::from_secs(3600);
    std::fs::File::options().write(true).open(&video).unwrap().set_modified(later).unwrap();
    let (again, r) = read(d.path(), &options);
    assert_eq!(counts(&r), (1, 0, 0), "a new modification time: decoded again");
    assert_eq!(again, before);
    assert_eq!(counts(&read(d.path(), &options).1), (0, 1, 0), "and cached again");

    // Our own encode of the same episodes: the same times, other pixels, another length.
    let ours = write(&d.path().join("ours"), &fixture_episodes(), FileLimits::default());
    let replacement = ours.join(VIDEO);
    assert_ne!(std::fs::metadata(&replacement).unwrap().len(), std::fs::metadata(&video).unwrap().len());
    std::fs::copy(&replacement, &video).unwrap();
    let (after, r) = read(d.path(), &options);
    assert_eq!(counts(&r), (1, 0, 0), "another length: decoded again");
    assert_ne!(after, before);
    assert_eq!(after, read(d.path(), &ReadOptions::no_cache()).0, "the new file's frames");
    assert_eq!(cache_files(cache.path()).len(), 1, "the entry replaced, not added");
}

/// A cache file cut short, made longer, or with a header that is not the file's is ignored (decoded again, never
/// read) and written again whole.
#[test]
fn a_damaged_cache_file_is_decoded_again_and_rewritten() {
    let cache = tempfile::tempdir().unwrap();
    let options = ReadOptions::cache_in(cache.path());
    let (want, _) = read(&fixture(), &options);
    let file = cache_files(cache.path()).remove(0);
    let good = std::fs::read(&file).unwrap();
    let mut damages: Vec<(&str, Vec<u8>)> = vec![
        ("cut short", good[..good.len() - 1].to_vec()),
        ("cut to its header", good[..100].to_vec()),
        ("empty", Vec::new()),
        ("longer", [&good[..], &[0u8; FRAME]].concat()),
    ];
    // The header's magic, format, source length, height, frame count and path, each changed.
    for (what, at) in [("magic", 0), ("format", 9), ("source length", 16), ("height", 40), ("frames", 48), ("path", 62)]
    {
        let mut bad = good.clone();
        bad[at] ^= 0x5a;
        damages.push((what, bad));
    }
    for (what, bytes) in damages {
        std::fs::write(&file, &bytes).unwrap();
        let (got, r) = read(&fixture(), &options);
        assert_eq!(counts(&r), (1, 0, 0), "{what}: decoded again");
        assert_eq!(got, want, "{what}");
        assert_eq!(std::fs::read(&file).unwrap(), good, "{what}: written again whole");
        assert_eq!(counts(&read(&fixture(), &options).1), (0, 1, 0), "{what}: then read from the cache");
    }
}

/// A cache folder that cannot be made (a file stands where it would be): every read decodes, with a warning,
/// and gives the frames.
#[test]
fn an_unwritable_cache_folder_still_reads_correctly() {
    let dir = tempfile::tempdir().unwrap();
    let blocker = dir.path().join("a-file");
    std::fs::write(&blocker, b"not a folder").unwrap();
    let options = ReadOptions::cache_in(&blocker.join("cache"));
    let (want, _) = read(&fixture(), &ReadOptions::no_cache());
    for _ in 0..2 {
        let (got, r) = read(&fixture(), &options);
        assert_eq!((r.decoded_files, r.cached_files), (1, 0));
        assert_eq!(got, want);
        assert_eq!(r.cache_warnings.len(), 1, "{:?}", r.cache_warnings);
        assert!(r.cache_warnings[0].contains("cannot make the cache folder"), "{}", r.cache_warnings[0]);
    }
}

/// A cache folder that can be made but not written to (a read-only folder, where the user is not root): reads
/// decode, warn that the file could not be written, and give the frames.
#[test]
fn a_cache_file_that_cannot_be_written_is_a_warning() {
    use std::os::unix::fs::PermissionsExt;
    let cache = tempfile::tempdir().unwrap();
    let options = ReadOptions::cache_in(cache.path());
    let (want, _) = read(&fixture(), &options);
    let file = cache_files(cache.path()).remove(0);
    let folder = file.parent().unwrap().to_owned();
    std::fs::remove_file(&file).unwrap();
    std::fs::set_permissions(&folder, std::fs::Permissions::from_mode(0o555)).unwrap();
    let (got, r) = read(&fixture(), &options);
    let writable = std::fs::write(folder.join("probe"), b"").is_ok(); // root writes anyway
    std::fs::set_permissions(&folder, std::fs::Permissions::from_mode(0o755)).unwrap();
    assert_eq!(got, want);
    assert_eq!((r.decoded_files, r.cached_files), (1, 0));
    if !writable {
        assert_eq!(r.cache_warnings.len(), 1, "{:?}", r.cache_warnings);
        assert!(r.cache_warnings[0].contains("cannot write the cache file"), "{}", r.cache_warnings[0]);
    }
}

#[test]
fn the_cache_can_be_turned_off() {
    let cache = tempfile::tempdir().unwrap();
    let options = ReadOptions { cache: false, cache_dir: Some(cache.path().to_owned()) };
    for _ in 0..2 {
        assert_eq!(counts(&read(&fixture(), &options).1), (1, 0, 0));
    }
    assert_eq!(std::fs::read_dir(cache.path()).unwrap().count(), 0, "nothing written");
}

/// `$MARS_CACHE_DIR`, else `$XDG_CACHE_HOME/mars/lerobot`, else `$HOME/.cache/mars/lerobot`; and a read with the
/// default options uses it. The only test here that reads or sets the environment.
#[test]
fn the_cache_folder_follows_the_environment() {
    use mars_lerobot::cache::default_dir;
    let dir = tempfile::tempdir().unwrap();
    let saved: Vec<_> = ["MARS_CACHE_DIR", "XDG_CACHE_HOME", "HOME"].map(|k| (k, std::env::var_os(k))).into();
    // Safety: no other test in this binary reads or writes the environment (each passes its cache folder).
    let set = |k: &str, v: Option<&Path>| unsafe {
        match v {
            Some(v) => std::env::set_var(k, v),
            None => std::env::remove_var(k),
        }
    };
    set("MARS_CACHE_DIR", Some(&dir.path().join("mars")));
    set("XDG_CACHE_HOME", Some(&dir.path().join("xdg")));
    set("HOME", Some(&dir.path().join("home")));
    assert_eq!(default_dir(), Some(dir.path().join("mars")));
    let (_, r) = LeRobotDataset::open(&fixture()).unwrap().read(&keys(), (64, 64)).unwrap();
    assert_eq!(counts(&r), (1, 0, 0));
    assert_eq!(cache_files(&dir.path().join("mars")).len(), 1, "the default read caches in $MARS_CACHE_DIR");
    set("MARS_CACHE_DIR", None);
    assert_eq!(default_dir(), Some(dir.path().join("xdg/mars/lerobot")));
    set("XDG_CACHE_HOME", Some(Path::new("")));
    assert_eq!(default_dir(), Some(dir.path().join("home/.cache/mars/lerobot")), "an empty variable is unset");
    set("XDG_CACHE_HOME", None);
    set("HOME", None);
    assert_eq!(default_dir(), None);
    for (k, v) in saved {
        set(k, v.as_deref().map(Path::new));
    }
}
