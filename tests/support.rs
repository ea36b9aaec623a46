//! Helpers shared by the test modules: the binary under test and scratch folders.

use std::path::PathBuf;
use std::process::Command;

/// The `onsager` binary built for these tests.
pub fn onsager() -> Command {
    Command::new(env!("CARGO_BIN_EXE_onsager"))
}

/// A scratch folder `onsager-AREA-PID-NAME` in the temporary directory, created (kept if it
/// exists).
pub fn scratch(area: &str, name: &str) -> PathBuf {
    let dir = scratch_path(area, name);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// The path of the scratch folder `onsager-AREA-PID-NAME`, removed if it exists and not created
/// (for commands that create their output folder themselves).
pub fn fresh_scratch(area: &str, name: &str) -> PathBuf {
    let dir = scratch_path(area, name);
    let _ = std::fs::remove_dir_all(&dir);
    dir
}

fn scratch_path(area: &str, name: &str) -> PathBuf {
    std::env::temp_dir().join(format!("onsager-{area}-{}-{name}", std::process::id()))
}
