//! Text that goes back to people and clients: one line, bounded, whatever the input echoed.

/// Longest message [`one_line`] returns, in characters (gRPC metadata carries statuses, and a
/// client that sent a huge name must get INVALID_ARGUMENT, not RESOURCE_EXHAUSTED).
pub const MAX_MESSAGE_CHARS: usize = 2000;

/// Longest name of a parameter, material, body, interface or QoI in a scene.
pub const MAX_NAME_CHARS: usize = 64;

/// A message on one line (toml's parse errors span several), at most [`MAX_MESSAGE_CHARS`].
pub fn one_line(text: &str) -> String {
    let joined = text.lines().map(str::trim).filter(|l| !l.is_empty()).collect::<Vec<_>>().join(" ");
    excerpt(&joined, MAX_MESSAGE_CHARS)
}

/// `text` cut to `max` characters, saying how much was left out.
pub fn excerpt(text: &str, max: usize) -> String {
    let total = text.chars().count();
    if total <= max {
        return text.to_string();
    }
    let kept: String = text.chars().take(max).collect();
    format!("{kept}... ({} more characters)", total - max)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn messages_are_one_bounded_line() {
        assert_eq!(one_line("a\n  b \n\n c"), "a b c");
        assert_eq!(excerpt("abcdef", 3), "abc... (3 more characters)");
        assert_eq!(excerpt("é", 1), "é");
        let huge = "x".repeat(100_000);
        assert!(one_line(&huge).len() < MAX_MESSAGE_CHARS + 40);
    }
}
