//! Writing to the terminal: results on stdout, messages on stderr, so that
//! neither stream can end raylab with a panic, an abort or a signal before
//! its files are written.
//!
//! Why: `println!` and `eprintln!` panic when a write fails, so `--json
//! >/dev/full` panicked, and `2>/dev/full` aborted (the panic hook's own
//! `eprintln!` panicked again) even after a successful render. With SIGPIPE's
//! default action, `render ... 2>&1 | head -1` was killed at its second line
//! on stderr, before it wrote the image. Now SIGPIPE is ignored
//! ([`crate::os::ignore_closed_pipe`]) and each stream decides:
//!
//! - stderr carries progress, warnings and errors for a person to read: a
//!   failed write is dropped and the work goes on ([`say`]);
//! - stdout carries the results: closed by the reader (EPIPE, as `| head`
//!   does), raylab ends quietly as every C tool does
//!   ([`crate::os::end_on_closed_pipe`]); any other failure is a one-line
//!   error naming stdout ([`out`]).

use std::io::Write;

use crate::error::{Error, Result};

/// Writes `line` and a newline to stderr; a failure is ignored (see the
/// module's note).
pub fn say(line: &str) {
    let mut e = std::io::stderr().lock();
    let _ = writeln!(e, "{line}");
}

/// Writes `text` to stdout as it is and flushes it: ends the process quietly
/// when the reader has closed the pipe, else fails in one line.
pub fn out(text: &str) -> Result<()> {
    let mut o = std::io::stdout().lock();
    let written = o.write_all(text.as_bytes()).and_then(|()| o.flush());
    match written {
        Ok(()) => Ok(()),
        Err(e) if e.kind() == std::io::ErrorKind::BrokenPipe => crate::os::end_on_closed_pipe(),
        Err(e) => Err(Error::io("stdout", e)),
    }
}

/// [`out`] with a newline after `text`.
pub fn outln(text: &str) -> Result<()> {
    out(&format!("{text}\n"))
}
