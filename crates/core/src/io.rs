//! Small file helpers shared by every stage: atomic writes and errors that name the file.
//!
//! Every output file of cac is written to a temporary sibling and renamed into place, so that a
//! killed job never leaves a half-written file where a finished one is expected.

use anyhow::{Context, Result};
use std::io::Write;
use std::path::Path;

/// Writes `bytes` to `path` atomically (temporary file in the same folder, fsync, rename).
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
    write_atomic_with(path, |w| w.write_all(bytes).map_err(Into::into))
}

/// Writes a file atomically through a writer callback (temporary sibling, fsync, rename); a
/// file streamed over a long stage (the sheets' PDF) is removed if the memory guard stops the
/// process before it is finished.
pub fn write_atomic_with(
    path: &Path,
    f: impl FnOnce(&mut std::io::BufWriter<&mut std::fs::File>) -> Result<()>,
) -> Result<()> {
    let dir = match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    };
    std::fs::create_dir_all(dir)
        .with_context(|| format!("cannot create output folder {}", dir.display()))?;
    let mut tmp = tempfile::Builder::new()
        .prefix(".cac-tmp-")
        .tempfile_in(dir)
        .with_context(|| format!("cannot write into output folder {}", dir.display()))?;
    // Removed, not left half-written, should the memory guard stop the process mid-write.
    let _on_stop = crate::memory::remove_on_stop(tmp.path());
    {
        let mut w = std::io::BufWriter::new(tmp.as_file_mut());
        f(&mut w).with_context(|| format!("while writing {}", path.display()))?;
        w.flush()
            .with_context(|| format!("while writing {}", path.display()))?;
    }
    // Temporary files are created 0600; a finished output file gets ordinary permissions.
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        let _ = tmp
            .as_file()
            .set_permissions(std::fs::Permissions::from_mode(0o644));
    }
    tmp.as_file()
        .sync_all()
        .with_context(|| format!("while syncing {}", path.display()))?;
    tmp.persist(path)
        .map_err(|e| e.error)
        .with_context(|| format!("cannot move finished file into place at {}", path.display()))?;
    Ok(())
}

/// Saves an 8-bit RGB image as PNG, atomically.
pub fn save_png_atomic(path: &Path, img: &image::RgbImage) -> Result<()> {
    let mut buf = Vec::new();
    img.write_to(&mut std::io::Cursor::new(&mut buf), image::ImageFormat::Png)
        .with_context(|| format!("cannot encode PNG for {}", path.display()))?;
    write_atomic(path, &buf)
}

/// Loads an image file as 8-bit RGB, with an error naming the file and what is wrong.
pub fn load_rgb(path: &Path) -> Result<image::RgbImage> {
    let bytes =
        std::fs::read(path).with_context(|| format!("cannot read image {}", path.display()))?;
    let img = image::load_from_memory(&bytes)
        .with_context(|| format!("{} is not a readable PNG/JPEG image", path.display()))?;
    Ok(img.to_rgb8())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn atomic_write_replaces_whole_file_and_leaves_no_temporaries() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("a.txt");
        write_atomic(&p, b"first version, long").unwrap();
        write_atomic(&p, b"second").unwrap();
        assert_eq!(std::fs::read(&p).unwrap(), b"second");
        let names: Vec<_> = std::fs::read_dir(dir.path()).unwrap().collect();
        assert_eq!(names.len(), 1, "a temporary file was left behind");
    }

    #[test]
    fn failed_write_keeps_the_old_file() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("a.txt");
        write_atomic(&p, b"kept").unwrap();
        let r = write_atomic_with(&p, |w| {
            w.write_all(b"partial")?;
            anyhow::bail!("simulated failure")
        });
        assert!(r.is_err());
        assert_eq!(std::fs::read(&p).unwrap(), b"kept");
    }

    #[test]
    fn unreadable_image_error_names_the_file() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("broken.png");
        std::fs::write(&p, b"\x89PNG\r\n\x1a\ntruncated").unwrap();
        let e = format!("{:#}", load_rgb(&p).unwrap_err());
        assert!(e.contains("broken.png"), "{e}");
    }
}
