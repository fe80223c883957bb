//! Every input a run of mars-fuzz found failing (in `fuzz/regressions`, named `<target>-<what>.bin`), decoded again:
//! each must now be refused or accepted, never panic or ask for more than the allocation cap.

use mars_fuzz::runner::check;

#[global_allocator]
static ALLOC: mars_fuzz::guard::CappedAlloc = mars_fuzz::guard::CappedAlloc;

#[test]
fn every_saved_failure_is_now_an_answer() {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("regressions");
    let targets = mars_fuzz::targets::all();
    let mut files: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|x| x == "bin"))
        .collect();
    files.sort();
    assert!(files.len() >= 5, "{} saved failures in {}", files.len(), dir.display());
    for file in files {
        let name = file.file_name().unwrap().to_string_lossy().into_owned();
        let target = targets
            .iter()
            .filter(|t| name.starts_with(&format!("{}-", t.name())))
            .max_by_key(|t| t.name().len())
            .unwrap_or_else(|| panic!("{name}: no target of that name"));
        let outcome = check(target.as_ref(), &std::fs::read(&file).unwrap());
        println!("{name}: {outcome:?}");
        assert!(outcome.is_ok(), "{name}: {outcome:?}");
    }
}
