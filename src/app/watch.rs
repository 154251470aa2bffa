//! File watching for hot reload: `notify` watches the shader and preset folders (and the
//! scene file) and the viewer drains the changed paths once per frame.

use notify::{RecursiveMode, Watcher};
use std::path::{Path, PathBuf};
use std::sync::mpsc::{channel, Receiver};

pub struct FileWatcher {
    // Kept alive: dropping the watcher stops the events.
    watcher: notify::RecommendedWatcher,
    events: Receiver<notify::Result<notify::Event>>,
    pub watched: Vec<PathBuf>,
}

impl FileWatcher {
    /// Watches the given folders or files; ones that do not exist are skipped.
    pub fn new(paths: &[PathBuf]) -> notify::Result<FileWatcher> {
        let (tx, events) = channel();
        let mut watcher = notify::recommended_watcher(move |e| {
            let _ = tx.send(e);
        })?;
        let mut watched = Vec::new();
        for p in paths {
            if let Ok(p) = p.canonicalize() {
                let mode = if p.is_dir() {
                    RecursiveMode::Recursive
                } else {
                    RecursiveMode::NonRecursive
                };
                watcher.watch(&p, mode)?;
                watched.push(p);
            }
        }
        Ok(FileWatcher {
            watcher,
            events,
            watched,
        })
    }

    /// Adds a file or folder (e.g. the scene file of a newly loaded preset).
    pub fn add(&mut self, p: &Path) {
        // Canonical, so `presets/../scene/x.gltf` is not mistaken for a file under presets/.
        let Ok(p) = p.canonicalize() else { return };
        let p = p.as_path();
        if !self.watched.iter().any(|w| p.starts_with(w)) {
            // The scene file's folder: editors often replace files by renaming.
            let target = if p.is_file() {
                p.parent().unwrap_or(p)
            } else {
                p
            };
            if self
                .watcher
                .watch(target, RecursiveMode::NonRecursive)
                .is_ok()
            {
                self.watched.push(target.to_path_buf());
            }
        }
    }

    /// Paths that changed (content or created/renamed) since the last call, deduplicated.
    pub fn drain(&self) -> Vec<PathBuf> {
        let mut out: Vec<PathBuf> = Vec::new();
        while let Ok(event) = self.events.try_recv() {
            let Ok(event) = event else { continue };
            if matches!(
                event.kind,
                notify::EventKind::Modify(_) | notify::EventKind::Create(_)
            ) {
                for p in event.paths {
                    if !out.contains(&p) {
                        out.push(p);
                    }
                }
            }
        }
        out
    }
}
