//! Text that goes back to people and clients: one line, bounded, whatever the input echoed.

/// Longest message [`one_line`] returns, in characters (gRPC metadata carries statuses, and a
/// client that sent a huge name must get INVALID_ARGUMENT, not RESOURCE_EXHAUSTED).
pub const MAX_MESSAGE_CHARS: usize = 2000;

/// Longest name of a parameter, material, body, interface or QoI in a scene.
pub const MAX_NAME_CHARS: usize = 64;

/// Whether `name` may name a parameter, material, body, interface or QoI: 1 to
/// [`MAX_NAME_CHARS`] printable characters, not all blank (names key records, label plots and
/// come back in messages).
pub fn is_plain_name(name: &str) -> bool {
    !name.trim().is_empty() && name.chars().count() <= MAX_NAME_CHARS && is_plain_text(name)
}

/// Whether a character would act on a terminal or a text's direction rather than print: the
/// control characters (NUL, ESC that starts an escape sequence, CR that rewrites a line, the C1
/// set with OSC) and the bidirectional overrides and isolates that reorder what follows.
pub fn is_unprintable(c: char) -> bool {
    c.is_control() || matches!(c, '\u{200e}' | '\u{200f}' | '\u{202a}'..='\u{202e}' | '\u{2066}'..='\u{2069}')
}

/// Whether `text` prints as it reads: no [`is_unprintable`] character (a label, a title, a unit).
pub fn is_plain_text(text: &str) -> bool {
    !text.chars().any(is_unprintable)
}

/// `text` with each [`is_unprintable`] character written as its escape (`\u{1b}`): what a
/// terminal, a log or a page can print whatever a client or a pool sent.
pub fn printable(text: &str) -> String {
    let mut out = String::with_capacity(text.len());
    for c in text.chars() {
        if is_unprintable(c) {
            out.extend(c.escape_unicode());
        } else {
            out.push(c);
        }
    }
    out
}

/// A message on one line (toml's parse errors span several), at most [`MAX_MESSAGE_CHARS`],
/// printable ([`printable`]: a pool's or a parser's message may echo anything).
pub fn one_line(text: &str) -> String {
    let joined = text.lines().map(str::trim).filter(|l| !l.is_empty()).collect::<Vec<_>>().join(" ");
    excerpt(&printable(&joined), MAX_MESSAGE_CHARS)
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

/// A CSV table (RFC 4180 quoting, by the `csv` crate), one record a line: the one writer of the
/// study results, the CLI's surface and the web page's `surface.csv`. A field that a spreadsheet
/// would take for a formula ([`spreadsheet_cell`]) is written as text.
pub fn csv_table<R, F>(records: impl IntoIterator<Item = R>) -> String
where
    R: IntoIterator<Item = F>,
    F: AsRef<[u8]>,
{
    let mut writer = csv::WriterBuilder::new().flexible(true).from_writer(Vec::new());
    for record in records {
        let cells: Vec<std::borrow::Cow<'_, [u8]>> =
            record.into_iter().map(|f| spreadsheet_cell(f.as_ref()).into_owned().into()).collect();
        // (in memory, and every field is text: nothing can fail)
        writer.write_record(&cells).expect("a CSV record in memory");
    }
    let bytes = writer.into_inner().expect("a CSV table in memory");
    String::from_utf8(bytes).expect("CSV of UTF-8 fields")
}

/// A CSV field as a spreadsheet should read it: one that starts like a formula (`=`, `+`, `-`,
/// `@`, a tab or a carriage return) and is not a number gets a leading `'`, which spreadsheets
/// take as "text" (a parameter named `=cmd|' /C calc'!A0` or `-2+3` must not run or compute);
/// a number, negative ones included, stays a number.
pub fn spreadsheet_cell(field: &[u8]) -> std::borrow::Cow<'_, [u8]> {
    let formula = matches!(field.first(), Some(b'=' | b'+' | b'-' | b'@' | b'\t' | b'\r'));
    let number = std::str::from_utf8(field).is_ok_and(|s| s.trim().parse::<f64>().is_ok());
    if formula && !number {
        let mut out = Vec::with_capacity(field.len() + 1);
        out.push(b'\'');
        out.extend_from_slice(field);
        out.into()
    } else {
        field.into()
    }
}

/// Significant digits of a parameter's value printed for people ([`parameter`]).
pub const PARAMETER_DIGITS: usize = 6;

/// A parameter's value for people: its shortest form at [`PARAMETER_DIGITS`] significant digits
/// at most (a grid's 0.11000000000000001 reads 0.11, an adaptive point's 0.19785156250000002
/// reads 0.197852: a box's points 1e-5 of its width apart stay apart). CSV and JSON keep the
/// stored value; [`same_parameter`] takes the printed text back.
pub fn parameter(value: f64) -> String {
    if !value.is_finite() || value == 0.0 {
        return format!("{value}");
    }
    let rounded: f64 = format!("{value:.*e}", PARAMETER_DIGITS - 1).parse().unwrap_or(value);
    format!("{rounded}")
}

/// Whether a stored parameter `value` is the one a user gave as `given` (a value printed by
/// [`parameter`], or the stored value itself).
pub fn same_parameter(value: f64, given: f64) -> bool {
    (value - given).abs() <= 1e-5 * given.abs().max(f64::MIN_POSITIVE)
}

/// A Unix time in milliseconds as `2026-11-25 18:30 UTC` (to the minute; empty for 0 or less:
/// not known).
pub fn utc_minute(unix_ms: i64) -> String {
    if unix_ms <= 0 {
        return String::new();
    }
    let (days, ms) = (unix_ms.div_euclid(86_400_000), unix_ms.rem_euclid(86_400_000));
    // the civil date of a day count (H. Hinnant's algorithm)
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let day = doy - (153 * mp + 2) / 5 + 1;
    let month = if mp < 10 { mp + 3 } else { mp - 9 };
    let year = yoe + era * 400 + i64::from(month <= 2);
    let minutes = ms / 60_000;
    format!("{year:04}-{month:02}-{day:02} {:02}:{:02} UTC", minutes / 60, minutes % 60)
}

/// A length of time for people: `42.0 s`, `3m05s`, `2h07m`.
pub fn wall_time(seconds: f64) -> String {
    let s = seconds.max(0.0);
    if s < 60.0 {
        format!("{s:.1} s")
    } else if s < 3600.0 {
        format!("{}m{:02}s", (s / 60.0) as u64, (s % 60.0) as u64)
    } else {
        format!("{}h{:02}m", (s / 3600.0) as u64, ((s % 3600.0) / 60.0) as u64)
    }
}

/// A study's audits and pilots' levels in a cell of a list (the CLI's and the web page's):
/// `-`, `4 ended`, `2 of 4 running`.
pub fn audits_cell(total: usize, active: usize) -> String {
    match (total, active) {
        (0, _) => "-".to_owned(),
        (n, 0) => format!("{n} ended"),
        (n, a) => format!("{a} of {n} running"),
    }
}

/// `x` rounded to 12 significant digits: a value made by arithmetic (2e-4 x 0.01 =
/// 2.0000000000000003e-6, 20 x 1e-6 = 1.9999999999999998e-5) becomes the decimal a user wrote or
/// would write, so JSON and text print it so; 12 digits stay far below any tolerance.
pub fn decimal(x: f64) -> f64 {
    if x.is_finite() { format!("{x:.11e}").parse().unwrap_or(x) } else { x }
}

/// A share (a relative error, an accuracy, a target) as every voice prints it: a percentage of 3
/// significant digits, to be said of what (issue 47: the same error read "3.3e-1" in `show` and
/// "32.72 %" in `refine`, and "largest 6.8e-8" never said relative to what).
pub fn percent(share: f64) -> String {
    let p = 100.0 * share;
    let a = p.abs();
    if !p.is_finite() {
        "unknown".into()
    } else if a == 0.0 {
        "0 %".into()
    } else if (0.01..1e4).contains(&a) {
        let decimals = (2 - a.log10().floor() as i32).max(0) as usize;
        format!("{p:.decimals$} %")
    } else {
        format!("{p:.1e} %")
    }
}

/// Significant digits of a QoI solved to `tolerance`: those the tolerance resolves and one more,
/// 3 to 8 (issue 47: 7 in the CLI, 5 on the web, all 17 in Python).
pub fn qoi_digits(tolerance: f64) -> usize {
    if tolerance > 0.0 && tolerance.is_finite() {
        ((-tolerance.log10()).ceil() as i64 + 1).clamp(3, 8) as usize
    } else {
        6
    }
}

/// A QoI's value as the CLI, the web page and Python write it: `digits` significant digits, and
/// exactly 0 below its resolution (a stuck slip's round-off: core::study::resolutions).
pub fn qoi_value(value: f64, digits: usize, resolution: f64) -> String {
    if !value.is_finite() {
        return value.to_string();
    }
    if value.abs() < resolution || value == 0.0 {
        return "0".into();
    }
    format!("{value:.*e}", digits.clamp(1, 17) - 1)
}

/// A point's error indicator as shown (`show`, the web page): `-` where the point has none (a
/// point that failed before its first iteration is stored with f64::MAX: records are JSON,
/// which has no NaN).
pub fn eta(value: f64) -> String {
    eta_of(measured_eta(value))
}

/// A point's error indicator as shown, where a message carries it as optional (`-`: none).
pub fn eta_of(value: Option<f64>) -> String {
    value.map_or_else(|| "-".to_owned(), |e| format!("{e:.2e}"))
}

/// A point's error indicator where it has one (None: failed before its first iteration, stored
/// as f64::MAX), as JSON and tables give it.
pub fn measured_eta(value: f64) -> Option<f64> {
    (value.is_finite() && value < f64::MAX).then_some(value)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shares_print_as_percentages_of_three_digits() {
        assert_eq!(percent(0.3272), "32.7 %");
        assert_eq!(percent(0.02), "2.00 %");
        assert_eq!(percent(1.5e-3), "0.150 %");
        assert_eq!(percent(6.8e-8), "6.8e-6 %");
        assert_eq!(percent(0.0), "0 %");
        assert_eq!(percent(f64::NAN), "unknown");
    }

    #[test]
    fn a_qoi_prints_the_digits_its_tolerance_resolves_and_exact_zeros() {
        assert_eq!((qoi_digits(1e-3), qoi_digits(2e-4), qoi_digits(1e-5), qoi_digits(1e-12)), (4, 5, 6, 8));
        assert_eq!(qoi_digits(0.5), 3);
        assert_eq!(qoi_value(2.94573e-5, 4, 1e-10), "2.946e-5");
        assert_eq!(qoi_value(-1234.5678, 5, 0.0), "-1.2346e3");
        // a stuck slip's round-off, below the resolution
        assert_eq!(qoi_value(4.67e-21, 4, 1.2e-10), "0");
        assert_eq!(qoi_value(0.0, 4, 0.0), "0");
    }

    #[test]
    fn a_value_made_by_arithmetic_reads_as_its_decimal() {
        assert_eq!(format!("{:?}", 2e-4 * 0.01), "2.0000000000000003e-6");
        assert_eq!(format!("{:?}", decimal(2e-4 * 0.01)), "2e-6");
        assert_eq!(format!("{:?}", decimal(98.0 * 2e-7)), "1.96e-5");
        assert_eq!(decimal(1e-3 * 0.01).to_bits(), 1e-5f64.to_bits());
        assert_eq!(decimal(0.1234567890123456), 0.123456789012);
        assert!(decimal(f64::NAN).is_nan() && decimal(f64::INFINITY) == f64::INFINITY);
    }

    #[test]
    fn an_eta_never_measured_is_a_dash() {
        assert_eq!(eta(1.234e-4), "1.23e-4");
        assert_eq!(eta(f64::MAX), "-");
        assert_eq!(eta(f64::NAN), "-");
    }

    #[test]
    fn a_csv_table_quotes_only_what_rfc_4180_asks_to() {
        let table = csv_table([
            vec!["name", "value"],
            vec!["plain", "1e-3"],
            vec!["a, b", "say \"hi\""],
            vec!["two\nlines", ""],
        ]);
        assert_eq!(table, "name,value\nplain,1e-3\n\"a, b\",\"say \"\"hi\"\"\"\n\"two\nlines\",\n");
    }

    /// Formula-looking fields are written as text; numbers, negative ones too, stay numbers.
    #[test]
    fn a_csv_table_writes_formulas_as_text() {
        let table = csv_table([
            vec!["=cmd|' /C calc'!A0", "+HYPERLINK(\"x\")", "-2+3", "@SUM(A1)", "\tx"],
            vec!["-2.5e-5", "+1", "-inf", "name-with-dash", "0"],
        ]);
        let mut lines = table.lines();
        assert_eq!(lines.next(), Some("'=cmd|' /C calc'!A0,\"'+HYPERLINK(\"\"x\"\")\",'-2+3,'@SUM(A1),'\tx"));
        assert_eq!(lines.next(), Some("-2.5e-5,+1,-inf,name-with-dash,0"));
    }

    /// Escapes, carriage returns, NUL, OSC and direction overrides come out as their escapes;
    /// other text, accents and CJK included, as it is.
    #[test]
    fn terminal_controls_are_printed_as_escapes() {
        let hostile = "a\u{1b}[2Jb\rc\0d\u{9d}e\u{202e}f\u{2066}g";
        assert!(!is_plain_text(hostile));
        let shown = printable(hostile);
        assert_eq!(shown, "a\\u{1b}[2Jb\\u{d}c\\u{0}d\\u{9d}e\\u{202e}f\\u{2066}g");
        assert!(is_plain_text(&shown));
        assert_eq!(printable("Ti-6Al-4V, 応力 ü"), "Ti-6Al-4V, 応力 ü");
        assert!(one_line("pool failed: \u{1b}]0;owned\u{7}").chars().all(|c| !is_unprintable(c)));
        assert!(!is_plain_name("f\u{202e}1"));
    }

    #[test]
    fn times_read_as_dates_and_durations() {
        assert_eq!(utc_minute(0), "");
        assert_eq!(utc_minute(86_400_000 - 60_000), "1970-01-01 23:59 UTC");
        // 2026-11-25 17:31:22 UTC
        assert_eq!(utc_minute(1_795_627_882_000), "2026-11-25 17:31 UTC");
        assert_eq!(utc_minute(951_782_400_000), "2000-02-29 00:00 UTC");
        assert_eq!(
            (wall_time(6.04), wall_time(185.0), wall_time(7620.0)),
            ("6.0 s".into(), "3m05s".into(), "2h07m".into())
        );
    }

    #[test]
    fn parameters_read_at_the_precision_they_need_and_their_text_finds_them() {
        assert_eq!(parameter(0.11000000000000001), "0.11");
        assert_eq!(parameter(0.19785156250000002), "0.197852");
        assert_eq!(parameter(0.10178326474622772), "0.101783");
        assert_eq!(
            (parameter(0.15), parameter(210e9), parameter(-2.5e-7), parameter(0.0)),
            ("0.15".into(), "210000000000".into(), "-0.00000025".into(), "0".into())
        );
        for v in [0.19785156250000002, 0.10178326474622772, 1.0000049, 9.9999951e-4] {
            assert!(same_parameter(v, parameter(v).parse().unwrap()), "{v}");
        }
        assert!(!same_parameter(0.1, 0.11) && !same_parameter(0.13, 0.15));
    }

    #[test]
    fn messages_are_one_bounded_line() {
        assert_eq!(one_line("a\n  b \n\n c"), "a b c");
        assert_eq!(excerpt("abcdef", 3), "abc... (3 more characters)");
        assert_eq!(excerpt("é", 1), "é");
        let huge = "x".repeat(100_000);
        assert!(one_line(&huge).len() < MAX_MESSAGE_CHARS + 40);
    }
}
