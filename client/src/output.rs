//! Standard output of the CLI. A reader that goes away early (`glissade surface 1 --json | head`)
//! ends the command quietly, as Unix tools do, instead of the panic of `println!`.

use std::borrow::Cow;
use std::fmt::Arguments;
use std::io::{ErrorKind, Write};

/// Writes to stdout, every character that would act on a terminal made inert ([`inert`]); exits
/// with status 0 when the reader has closed the pipe. Any other write error is reported on
/// stderr with status 1.
pub fn write(args: Arguments<'_>) {
    let text = args.to_string();
    let mut out = std::io::stdout().lock();
    if let Err(e) = out.write_all(inert(&text).as_bytes()).and_then(|()| out.flush()) {
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

/// `text` with each character that would act on a terminal (a control but a newline or a tab: ESC,
/// CR, NUL, C1; a direction override: core::text::is_unprintable) written as its JSON escape
/// `\u001b`, which inside a JSON string means the very character (issue 48: labels and messages
/// stored before the checks at submit, or sent by a server that is not ours, were printed raw).
pub fn inert(text: &str) -> Cow<'_, str> {
    let acts = |c: char| c != '\n' && c != '\t' && glissade_core::text::is_unprintable(c);
    if !text.chars().any(acts) {
        return Cow::Borrowed(text);
    }
    Cow::Owned(text.chars().map(|c| if acts(c) { format!("\\u{:04x}", c as u32) } else { c.to_string() }).collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn what_would_act_on_a_terminal_is_written_inert_and_json_keeps_its_meaning() {
        assert_eq!(inert("study 3 (plain)\n\tok"), "study 3 (plain)\n\tok");
        assert_eq!(inert("a\u{1b}]0;owned\u{7}b\r\u{0}"), "a\\u001b]0;owned\\u0007b\\u000d\\u0000");
        assert_eq!(inert("left \u{202e}thgir"), "left \\u202ethgir");
        // JSON as serde writes it (controls escaped, an override raw) reads back the same
        let value = serde_json::json!({"label": "x\u{202e}y\u{1b}z"});
        let written = inert(&value.to_string()).into_owned();
        assert!(!written.contains('\u{202e}'), "{written}");
        assert_eq!(serde_json::from_str::<serde_json::Value>(&written).unwrap(), value);
    }
}
