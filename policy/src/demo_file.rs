//! The demo files `mars demos` writes and every command reads (JSON of a `DemoSet`), written through a temporary
//! name so a crash never leaves half a file.

use anyhow::Context;
use mars_tasks::demo::DemoSet;
use std::path::Path;

pub fn load_demos(path: &Path) -> anyhow::Result<DemoSet> {
    let text = std::fs::read_to_string(path)
        .with_context(|| format!("cannot read demos {} (generate them with `mars demos`)", path.display()))?;
    serde_json::from_str(&text).with_context(|| format!("{} is not a valid demo file", path.display()))
}

pub(crate) fn write_json(path: &Path, value: &impl serde::Serialize) -> anyhow::Result<()> {
    if let Some(dir) = path.parent() {
        std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    }
    let tmp = path.with_extension("json.tmp");
    std::fs::write(&tmp, serde_json::to_string(value)?).with_context(|| format!("cannot write {}", tmp.display()))?;
    std::fs::rename(&tmp, path).with_context(|| format!("cannot write {}", path.display()))
}
