//! Files the whole project reads and writes: stored interface solutions (`solution_file`, the warm
//! starts of docs/method.md 4) and the atomic, durable write every file output goes through.

pub mod solution_file;
use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::Path;

/// Writes a file atomically: `write` fills a temporary file in the same directory, which is then
/// synced and renamed over `path`, so a reader never sees a half-written file and a failed write
/// leaves any previous file in place (the temporary file is removed).
pub fn write_atomically<E: From<std::io::Error>>(
    path: &Path,
    write: impl FnOnce(&mut BufWriter<&File>) -> Result<(), E>,
) -> Result<(), E> {
    replace_atomically(path, |_, file| {
        let mut w = BufWriter::new(file);
        write(&mut w)?;
        w.flush()?;
        Ok(())
    })
}

/// Like [`write_atomically`] for writers that open the file themselves (HDF5): `write` gets the
/// temporary file's path (and the file, already created and empty).
pub fn replace_atomically<E: From<std::io::Error>>(
    path: &Path,
    write: impl FnOnce(&Path, &File) -> Result<(), E>,
) -> Result<(), E> {
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    let mut builder = tempfile::Builder::new();
    builder.prefix(".glissade-").suffix(".tmp");
    // an ordinary file's permissions (tempfile's default, 0600, is for secrets)
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        builder.permissions(std::fs::Permissions::from_mode(0o644));
    }
    let tmp = builder.tempfile_in(dir)?;
    write(tmp.path(), tmp.as_file())?;
    File::open(tmp.path())?.sync_all()?;
    tmp.persist(path).map_err(|e| e.error)?;
    // the rename itself is durable only once the directory is synced
    File::open(dir)?.sync_all()?;
    Ok(())
}
