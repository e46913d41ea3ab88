//! Standard output of the CLI. A reader that goes away early (`glissade surface 1 --json | head`)
//! ends the command quietly, as Unix tools do, instead of the panic of `println!`.

use std::fmt::Arguments;
use std::io::{ErrorKind, Write};

/// Writes to stdout; exits with status 0 when the reader has closed the pipe. Any other write
/// error is reported on stderr with status 1.
pub fn write(args: Arguments<'_>) {
    let mut out = std::io::stdout().lock();
    if let Err(e) = out.write_fmt(args).and_then(|()| out.flush()) {
        if e.kind() == ErrorKind::BrokenPipe {
            std::process::exit(0);
        }
        eprintln!("error: writing to stdout: {e}");
        std::process::exit(1);
    }
}

/// `println!` through [`write`].
#[macro_export]
macro_rules! outln {
    () => { $crate::output::write(format_args!("\n")) };
    ($($arg:tt)*) => { $crate::output::write(format_args!("{}\n", format_args!($($arg)*))) };
}

/// `print!` through [`write`].
#[macro_export]
macro_rules! out {
    ($($arg:tt)*) => { $crate::output::write(format_args!($($arg)*)) };
}
