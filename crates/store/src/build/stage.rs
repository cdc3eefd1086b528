//! Points of a build where a test looks at what the build has written so far:
//! the files a SIGKILL at that point would leave behind. Nothing outside the
//! crate's own tests sees them.

#[cfg(test)]
mod hook {
    use std::cell::RefCell;

    type Hook = Box<dyn FnMut(&'static str)>;

    thread_local! {
        static HOOK: RefCell<Option<Hook>> = RefCell::new(None);
    }

    /// Calls `f` at every stage the builds on this thread reach, while `run`
    /// runs.
    pub(crate) fn with<T>(f: impl FnMut(&'static str) + 'static, run: impl FnOnce() -> T) -> T {
        HOOK.with(|h| *h.borrow_mut() = Some(Box::new(f)));
        let r = run();
        HOOK.with(|h| *h.borrow_mut() = None);
        r
    }

    pub(crate) fn reached(stage: &'static str) {
        HOOK.with(|h| {
            if let Some(f) = h.borrow_mut().as_mut() {
                f(stage)
            }
        });
    }
}

#[cfg(test)]
pub(crate) use hook::{reached, with};

/// The build reached `stage` (a no-op outside the crate's tests).
#[cfg(not(test))]
#[inline(always)]
pub(crate) fn reached(_stage: &'static str) {}

#[cfg(test)]
mod tests {
    use crate::error::StoreError;
    use crate::partial::temporary_pid;
    use crate::{BuildOptions, build};
    use brickray_core::{Volume, VolumeData};
    use std::cell::RefCell;
    use std::path::{Path, PathBuf};
    use std::rc::Rc;

    /// Copies every build temporary in `dir` into `to`, under its own name.
    fn snapshot(dir: &Path, to: &Path) -> Vec<PathBuf> {
        std::fs::create_dir_all(to).unwrap();
        let mut out = Vec::new();
        for e in std::fs::read_dir(dir).unwrap() {
            let e = e.unwrap();
            if temporary_pid(&e.file_name()).is_some() {
                let copy = to.join(e.file_name());
                std::fs::copy(e.path(), &copy).unwrap();
                out.push(copy);
            }
        }
        out
    }

    /// A banded build (the memory bound too small for one streaming pass),
    /// looked at after its node table is written, after its header is
    /// written and just before the rename: each temporary a SIGKILL there
    /// would leave is refused by `open` with a typed error. Until the magic
    /// is written (after everything else is synced) its bytes are not a
    /// store under any name; in the last instants before the rename they
    /// are, and `open` refuses the file by its temporary name. With spreads
    /// too (their payloads' and the banded levels' moments' temporaries).
    #[test]
    fn an_interrupted_build_leaves_nothing_that_opens_as_a_store() {
        for spread in [false, true] {
            interrupted_build(spread);
        }
    }

    fn interrupted_build(spread: bool) {
        let dims = [200u32, 300, 50];
        let n = dims.iter().map(|&d| d as usize).product::<usize>();
        let data = (0..n).map(|i| (i * 7 % 251) as u8).collect();
        let vol = Volume::with_data_range(dims, [1.0; 3], VolumeData::U8(data)).unwrap();
        let mut reader = brickray_io::MemoryReader::new(vol, "memory");
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("v.brs");
        let snaps = tempfile::tempdir().unwrap();
        type Seen = Vec<(&'static str, Vec<PathBuf>)>;
        let seen: Rc<RefCell<Seen>> = Rc::default();
        let opts = BuildOptions {
            brick: 8,
            // The moments' band rows need more than the values'.
            memory_bound: if spread { 3_000_000 } else { 1_500_000 },
            spread,
            ..BuildOptions::default()
        };
        let report = {
            let (seen, d, s) = (seen.clone(), dir.path().to_owned(), snaps.path().to_owned());
            super::with(
                move |stage| {
                    let files = snapshot(&d, &s.join(stage));
                    seen.borrow_mut().push((stage, files));
                },
                || build(&mut reader, &out, &opts).unwrap(),
            )
        };
        assert!(report.banded_levels >= 1, "{report:?}");
        let seen = seen.borrow();
        let stages: Vec<&str> = seen.iter().map(|s| s.0).collect();
        assert_eq!(stages, ["table", "header", "rename"]);
        for (stage, files) in seen.iter() {
            assert!(!files.is_empty(), "{stage}: no temporary");
            for f in files {
                match crate::open(f) {
                    Err(StoreError::NotAStore { .. } | StoreError::PartialBuild { .. }) => {}
                    Ok(_) => panic!("{stage}: {} opens as a store", f.display()),
                    Err(e) => panic!("{stage}: {}: unexpected error {e}", f.display()),
                }
                // The bytes alone, under a store's name.
                let plain = f.with_file_name("plain.brs");
                std::fs::copy(f, &plain).unwrap();
                let opened = crate::open(&plain).map(|_| "a store");
                if *stage == "rename" {
                    // Complete but for the rename: only the name refuses it.
                    continue;
                }
                assert!(
                    matches!(opened, Err(StoreError::NotAStore { .. })),
                    "{stage}: the bytes of {} open as {opened:?}",
                    f.display()
                );
            }
        }
        // The output opens, and no temporary is left.
        crate::open(dir.path().join("v.brs")).unwrap();
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
    }
}
