//! Opening the files a run reads (scenes, topologies, reference images):
//! regular files only, of at most `MAX_INPUT_BYTES`. Without these checks
//! a scene named `/dev/zero` (or a link to it) was read until memory ran
//! out, and a named pipe blocked the run until something wrote to it.
//! Refusals are `Error::Read`, naming the path and why.

use std::fs::File;
use std::io::{self, Read};
use std::path::Path;

use crate::{Error, Result};

/// The largest input file read: 1 GiB. Far beyond any scene, topology or
/// reference image a render can use (the largest bundled scene is a few
/// MiB, and the loader needs several times a file's size in memory), and
/// low enough that a wrong path fails at once instead of filling memory.
pub const MAX_INPUT_BYTES: u64 = 1 << 30;

/// `MAX_INPUT_BYTES` as messages say it.
const LIMIT: &str = "1 GiB";

/// Opens `path` for reading; refused unless it is a regular file (links
/// followed) of at most `MAX_INPUT_BYTES`.
pub fn open(path: &Path) -> Result<File> {
    use std::os::unix::fs::OpenOptionsExt;
    // Non-blocking, so that opening a named pipe returns at once (to be
    // refused below) instead of waiting for a writer. The flag does
    // nothing to reads of the regular files that pass.
    let file = std::fs::OpenOptions::new()
        .read(true)
        .custom_flags(libc::O_NONBLOCK)
        .open(path)
        .map_err(|source| refused(path, source))?;
    // The type and size of what was opened, not of what the path named a
    // moment before.
    let meta = file.metadata().map_err(|source| refused(path, source))?;
    if !meta.is_file() {
        return Err(refused(
            path,
            io::Error::new(
                io::ErrorKind::InvalidInput,
                format!("is {}, not a regular file", kind(&meta.file_type())),
            ),
        ));
    }
    if meta.len() > MAX_INPUT_BYTES {
        return Err(refused(path, too_large(Some(meta.len()))));
    }
    Ok(file)
}

/// The whole of `path` (see `open`). At most `MAX_INPUT_BYTES` are read
/// even if the file grows meanwhile or says it is empty (as files of
/// `/proc` do).
pub fn read(path: &Path) -> Result<Vec<u8>> {
    let file = open(path)?;
    let mut bytes = Vec::new();
    file.take(MAX_INPUT_BYTES + 1)
        .read_to_end(&mut bytes)
        .map_err(|source| refused(path, source))?;
    if bytes.len() as u64 > MAX_INPUT_BYTES {
        return Err(refused(path, too_large(None)));
    }
    Ok(bytes)
}

/// The whole of `path` as UTF-8 text (see `read`); other bytes are a read
/// error, as `std::fs::read_to_string` makes them.
pub fn read_to_string(path: &Path) -> Result<String> {
    String::from_utf8(read(path)?).map_err(|_| {
        refused(
            path,
            io::Error::new(
                io::ErrorKind::InvalidData,
                "stream did not contain valid UTF-8",
            ),
        )
    })
}

fn refused(path: &Path, source: io::Error) -> Error {
    Error::Read {
        path: path.to_path_buf(),
        source,
    }
}

fn too_large(len: Option<u64>) -> io::Error {
    let what = match len {
        Some(n) => format!("is {n} bytes"),
        None => "is larger".to_string(),
    };
    io::Error::new(
        io::ErrorKind::InvalidInput,
        format!("{what}, more than the {LIMIT} an input file may be"),
    )
}

/// What a file that is not a regular file is, for messages.
fn kind(t: &std::fs::FileType) -> &'static str {
    use std::os::unix::fs::FileTypeExt;
    if t.is_dir() {
        "a folder"
    } else if t.is_fifo() {
        "a named pipe"
    } else if t.is_char_device() {
        "a character device"
    } else if t.is_block_device() {
        "a block device"
    } else if t.is_socket() {
        "a socket"
    } else {
        "a special file"
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn message(r: Result<Vec<u8>>) -> String {
        r.expect_err("refused").to_string()
    }

    #[test]
    fn folders_and_devices_are_refused_by_what_they_are() {
        let dir = tempfile::tempdir().unwrap();
        let e = message(read(dir.path()));
        assert!(
            e.ends_with("cannot read: is a folder, not a regular file"),
            "{e}"
        );
        assert!(e.starts_with(&dir.path().display().to_string()), "{e}");
        // Refused before a byte is read: /dev/zero never ends.
        let e = message(read(Path::new("/dev/zero")));
        assert_eq!(
            e,
            "/dev/zero: cannot read: is a character device, not a regular file"
        );
    }

    #[test]
    fn files_above_the_limit_are_refused_naming_it() {
        let dir = tempfile::tempdir().unwrap();
        let big = dir.path().join("big.ron");
        // Sparse: no gigabyte is written.
        File::create(&big)
            .unwrap()
            .set_len(MAX_INPUT_BYTES + 1)
            .unwrap();
        let e = message(read(&big));
        assert!(
            e.ends_with(
                "cannot read: is 1073741825 bytes, more than the 1 GiB an input file may be"
            ),
            "{e}"
        );
        let small = dir.path().join("small.ron");
        std::fs::write(&small, b"()").unwrap();
        assert_eq!(read(&small).unwrap(), b"()");
    }

    /// A file that says it is empty is read whole all the same.
    #[test]
    fn files_that_report_no_size_are_read_whole() {
        let text = read_to_string(Path::new("/proc/self/status")).unwrap();
        assert!(text.contains("Name:"), "{text}");
    }
}
