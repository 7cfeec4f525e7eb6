//! A single-pass, allocation-light tokenizer for model answers.
//!
//! It never backtracks and never recurses, so any input (binary junk, megabytes
//! of digits, deeply nested brackets) is scanned in linear time. It knows just
//! enough to find numbers and structure:
//!
//! * a **number** is `[sign] digits [. digits] [e [sign] digits]` (or `.5`), where
//!   the sign may be `-`, `+`, the unicode minus `−` or an en dash `–`, attached
//!   when it does not follow a word or number; the words `nan`, `inf` and
//!   `infinity` are numbers too (non-finite, so they never pass);
//! * a **bad number** looks numeric but is not one: fused numbers (`3.7640.002`),
//!   leading zeros (`0001`, a lost decimal point), a doubled sign (`--0.01`, `+-0.5`);
//! * a number glued to a word (`v1`, `step2`, `0.5s`, `c_1`) is part of that word;
//! * a **label** is a number that is not a value: `Step 1:` (followed by `:`), a list
//!   marker `2.` or `2)` at the start of a line, or a number describing the horizon
//!   (`3 seconds`, `0.5 s`, `6 steps`);
//! * a **unit** (`m/s`, `1/m`, `/m`, `rad/m`, `m^-1`) is skipped by the parser;
//! * an **operator** is `+ - * /` (or `− – × ÷`) not attached to a number;
//! * brackets `(`/`[`/`{` and `)`/`]`/`}`, commas and semicolons are tokens;
//!   words are `Word` (a `label` word looks like `v1`, `κ2`, `step`, `speed`);
//!   anything else is `Other`.

/// A token and its byte range in the answer.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Token {
    pub kind: Kind,
    pub pos: usize,
    pub end: usize,
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Kind {
    /// A number; `plain` is false for unicode signs and `nan`/`inf` words, `signed`
    /// is true when a sign is attached.
    Num {
        value: f64,
        plain: bool,
        signed: bool,
    },
    /// Looks numeric but is not a number.
    Bad(BadNum),
    /// `+ - * /` not attached to a number (`plain` false for `− – × ÷`).
    Op {
        op: u8,
        plain: bool,
    },
    Unit,
    Label,
    Open(u8),
    Close(u8),
    Comma,
    Semicolon,
    Word {
        label: bool,
    },
    Other,
}

/// Why a numeric-looking token is not a number.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum BadNum {
    /// Two numbers run together (`3.7640.002`).
    Fused,
    /// An integer part with leading zeros (`0001`, `05.5`): a lost decimal point.
    LeadingZeros,
    /// Two signs before a number (`--0.01`, `+-0.5`): neither sign can be trusted.
    DoubledSign,
}

const MINUS_SIGNS: [char; 2] = ['\u{2212}', '\u{2013}'];

fn is_word_char(c: char) -> bool {
    if c.is_ascii() {
        c.is_ascii_alphanumeric() || c == '_'
    } else {
        c.is_alphanumeric()
    }
}

/// Words that look like labels of a value (`v`, `speed`, `step`, …); any word with a digit does too.
const LABEL_WORDS: &[&str] = &[
    "v",
    "c",
    "k",
    "κ",
    "kappa",
    "t",
    "time",
    "step",
    "steps",
    "speed",
    "velocity",
    "curvature",
    "curv",
    "action",
    "actions",
    "pair",
    "pairs",
    "answer",
    "final",
];

/// Words that make the number before them prose about the horizon, not an action:
/// `3 seconds`, `0.5 s`, `6 steps`, `6 pairs`.
const HORIZON_WORDS: &[&str] = &[
    "s",
    "sec",
    "secs",
    "second",
    "seconds",
    "step",
    "steps",
    "timestep",
    "timesteps",
    "action",
    "actions",
    "pair",
    "pairs",
    "frame",
    "frames",
    "hz",
    "ms",
];

/// Tokenize `text` into `out` (cleared first). `scratch` is reused for number text.
/// Returns whether the text may hold a reasoning tag (it has a `<` or a `◁`).
pub fn tokenize(text: &str, out: &mut Vec<Token>, scratch: &mut String) -> bool {
    out.clear();
    tokenize_range(text, 0, text.len(), out, scratch)
}

/// Tokenize `text[start..end]` (char boundaries), appending to `out`; returns
/// whether the range has a `<` or a `◁`.
pub fn tokenize_range(
    text: &str,
    start: usize,
    end: usize,
    out: &mut Vec<Token>,
    scratch: &mut String,
) -> bool {
    let mut maybe_tags = false;
    let text_all = text;
    let text = &text_all[..end];
    let bytes = text.as_bytes();
    let mut i = start;
    // whether the previous character (if any) belongs to a word or number
    let mut prev_word = false;
    // whether only whitespace precedes on the current line
    let mut line_start = true;
    let push = |out: &mut Vec<Token>, kind: Kind, pos: usize, end: usize| {
        out.push(Token { kind, pos, end });
    };
    while i < bytes.len() {
        let b = bytes[i];
        let (c, width) = if b < 0x80 {
            (b as char, 1)
        } else {
            // `text` is valid UTF-8, so a char starts here
            let c = text[i..].chars().next().unwrap_or('\u{FFFD}');
            maybe_tags |= c == '\u{25c1}';
            (c, c.len_utf8())
        };
        let space = if b < 0x80 {
            matches!(b, b' ' | b'\t'..=b'\r')
        } else {
            c.is_whitespace()
        };
        if space {
            prev_word = false;
            line_start |= c == '\n';
            i += width;
            continue;
        }
        let start = i;
        let at_line_start = line_start;
        line_start = false;
        // numbers, possibly signed
        let sign = if b < 0x80 {
            b == b'-' || b == b'+'
        } else {
            MINUS_SIGNS.contains(&c)
        };
        let signed = sign && !prev_word;
        if signed {
            if let Some(end) = doubled_sign(text, i + width) {
                push(out, Kind::Bad(BadNum::DoubledSign), start, end);
                prev_word = true;
                i = end;
                continue;
            }
        }
        let num_start = if signed { i + width } else { i };
        if (signed || !prev_word) && starts_number(bytes, num_start) {
            let mut end = scan_number(bytes, num_start);
            let glued = text[end..].chars().next().is_some_and(is_word_char);
            if glued {
                // e.g. `0.5s`, `1st`: part of a word
                let end = scan_word(text, end);
                push(out, Kind::Word { label: true }, start, end);
                prev_word = true;
                i = end;
                continue;
            }
            if let Some(unit_end) = unit_after_one(text, num_start, end) {
                push(out, Kind::Unit, start, unit_end);
                prev_word = true;
                i = unit_end;
                continue;
            }
            if is_label(bytes, num_start, end, at_line_start && !signed)
                || describes_horizon(text, end)
            {
                push(out, Kind::Label, start, end);
                prev_word = true;
                i = end;
                continue;
            }
            let bad = if bytes.get(end) == Some(&b'.')
                && bytes.get(end + 1).is_some_and(u8::is_ascii_digit)
            {
                // `3.7640.002`: swallow the whole run of digits and dots
                while end < bytes.len() && (bytes[end].is_ascii_digit() || bytes[end] == b'.') {
                    end += 1;
                }
                Some(BadNum::Fused)
            } else if leading_zeros(&bytes[num_start..end]) {
                Some(BadNum::LeadingZeros)
            } else {
                None
            };
            if let Some(bad) = bad {
                push(out, Kind::Bad(bad), start, end);
                prev_word = true;
                i = end;
                continue;
            }
            scratch.clear();
            if signed {
                scratch.push(if c == '+' { '+' } else { '-' });
            }
            scratch.push_str(&text[num_start..end]);
            let value = scratch.parse::<f64>().unwrap_or(f64::NAN);
            push(
                out,
                Kind::Num {
                    value,
                    plain: !MINUS_SIGNS.contains(&c),
                    signed,
                },
                start,
                end,
            );
            // a sign right after a number is an operator (`3-4`), not a sign
            prev_word = true;
            i = end;
            continue;
        }
        if is_word_char(c) {
            let end = scan_word(text, i);
            if let Some(unit_end) = unit_at_word(text, i, end) {
                push(out, Kind::Unit, start, unit_end);
                prev_word = true;
                i = unit_end;
                continue;
            }
            let word = &text[i..end];
            let kind = if word.eq_ignore_ascii_case("nan") {
                Kind::Num {
                    value: f64::NAN,
                    plain: false,
                    signed: false,
                }
            } else if word.eq_ignore_ascii_case("inf") || word.eq_ignore_ascii_case("infinity") {
                Kind::Num {
                    value: f64::INFINITY,
                    plain: false,
                    signed: false,
                }
            } else {
                Kind::Word {
                    label: is_label_word(word),
                }
            };
            push(out, kind, start, end);
            prev_word = true;
            i = end;
            continue;
        }
        let kind = match c {
            '(' | '[' | '{' => Kind::Open(b),
            ')' | ']' | '}' => Kind::Close(b),
            ',' => Kind::Comma,
            ';' => Kind::Semicolon,
            '/' if unit_slash_m(bytes, i + 1) => {
                push(out, Kind::Unit, start, i + 2);
                prev_word = true;
                i += 2;
                continue;
            }
            '+' | '-' | '*' | '/' => Kind::Op { op: b, plain: true },
            '\u{2212}' | '\u{2013}' => Kind::Op {
                op: b'-',
                plain: false,
            },
            '\u{00d7}' => Kind::Op {
                op: b'*',
                plain: false,
            },
            '\u{00f7}' => Kind::Op {
                op: b'/',
                plain: false,
            },
            '<' => {
                maybe_tags = true;
                Kind::Other
            }
            _ => Kind::Other,
        };
        push(out, kind, start, i + width);
        prev_word = false;
        i += width;
    }
    maybe_tags
}

/// A second sign at `i` followed by a number (`--0.01`): the end of that number.
fn doubled_sign(text: &str, i: usize) -> Option<usize> {
    let c = text[i..].chars().next()?;
    if !(c == '-' || c == '+' || MINUS_SIGNS.contains(&c)) {
        return None;
    }
    let j = i + c.len_utf8();
    starts_number(text.as_bytes(), j).then(|| scan_number(text.as_bytes(), j))
}

/// Whether the number `bytes[num_start..end]` is a label: `1:`, a list marker `1.` or
/// `1)` at the start of a line (`list_position`), or `3/s`-like.
fn is_label(bytes: &[u8], num_start: usize, end: usize, list_position: bool) -> bool {
    let small_int = || end - num_start <= 2 && bytes[num_start..end].iter().all(u8::is_ascii_digit);
    match bytes.get(end) {
        Some(b':') => true,
        Some(b'.') => list_position && bytes.get(end + 1).is_none_or(u8::is_ascii_whitespace),
        Some(b')') => {
            list_position
                && small_int()
                && bytes[num_start] != b'0'
                && matches!(bytes.get(end + 1), Some(b' ' | b'\t'))
        }
        Some(b'/') => bytes.get(end + 1).is_some_and(u8::is_ascii_alphabetic),
        _ => false,
    }
}

/// `0001`, `05.5`: an integer part of two or more digits that starts with 0.
fn leading_zeros(number: &[u8]) -> bool {
    let int_len = number.iter().take_while(|b| b.is_ascii_digit()).count();
    int_len >= 2 && number[0] == b'0'
}

/// Whether the number ending at `end` is followed (after spaces) by a horizon word.
fn describes_horizon(text: &str, end: usize) -> bool {
    let bytes = text.as_bytes();
    let mut i = end;
    while matches!(bytes.get(i), Some(b' ' | b'\t')) {
        i += 1;
    }
    if i == end {
        return false; // `3s` is a word of its own; `3,` is no prose
    }
    let start = i;
    while i < bytes.len() && i - start <= 9 && bytes[i].is_ascii_alphabetic() {
        i += 1;
    }
    let word = &bytes[start..i];
    if word.is_empty() || word.len() > 9 || text[i..].chars().next().is_some_and(is_word_char) {
        return false;
    }
    HORIZON_WORDS
        .iter()
        .any(|w| w.len() == word.len() && w.as_bytes().eq_ignore_ascii_case(word))
}

/// Whether a word looks like a label: it holds a digit (`v1`, `κ2`) or is one of `LABEL_WORDS`.
fn is_label_word(word: &str) -> bool {
    word.bytes().any(|b| b.is_ascii_digit())
        || (word.len() <= 9
            && LABEL_WORDS.iter().any(|w| {
                w.len() == word.len() && w.as_bytes().eq_ignore_ascii_case(word.as_bytes())
            }))
}

/// `/m` not followed by a word character (the unit 1/m's tail).
fn unit_slash_m(bytes: &[u8], i: usize) -> bool {
    bytes.get(i) == Some(&b'm')
        && !bytes
            .get(i + 1)
            .is_some_and(|&b| b.is_ascii_alphanumeric() || b == b'_')
}

/// The number `1` of `1/m`: the end of the unit.
fn unit_after_one(text: &str, num_start: usize, end: usize) -> Option<usize> {
    (&text[num_start..end] == "1"
        && unit_slash_m(text.as_bytes(), end + 1)
        && text.as_bytes()[end] == b'/')
        .then_some(end + 2)
}

/// A unit starting with the word `text[i..word_end]`: `m/s`, `rad/m`, `m^-1`, `m⁻¹`.
fn unit_at_word(text: &str, i: usize, word_end: usize) -> Option<usize> {
    let word = &text[i..word_end];
    let rest = &text[word_end..];
    let tail_ok = |len: usize| !rest[len..].chars().next().is_some_and(is_word_char);
    if word == "m" {
        for tail in ["/s", "^-1", "\u{207b}\u{00b9}"] {
            if rest.starts_with(tail) && tail_ok(tail.len()) {
                return Some(word_end + tail.len());
            }
        }
    }
    if word == "rad" && rest.starts_with("/m") && tail_ok(2) {
        return Some(word_end + 2);
    }
    None
}

fn starts_number(bytes: &[u8], i: usize) -> bool {
    match bytes.get(i) {
        Some(b) if b.is_ascii_digit() => true,
        Some(b'.') => bytes.get(i + 1).is_some_and(u8::is_ascii_digit),
        _ => false,
    }
}

/// End of the number starting at `i` (which `starts_number` accepted).
fn scan_number(bytes: &[u8], mut i: usize) -> usize {
    while i < bytes.len() && bytes[i].is_ascii_digit() {
        i += 1;
    }
    if i < bytes.len() && bytes[i] == b'.' && bytes.get(i + 1).is_some_and(u8::is_ascii_digit) {
        i += 1;
        while i < bytes.len() && bytes[i].is_ascii_digit() {
            i += 1;
        }
    }
    if i < bytes.len() && (bytes[i] == b'e' || bytes[i] == b'E') {
        let mut j = i + 1;
        if j < bytes.len() && (bytes[j] == b'+' || bytes[j] == b'-') {
            j += 1;
        }
        if j < bytes.len() && bytes[j].is_ascii_digit() {
            while j < bytes.len() && bytes[j].is_ascii_digit() {
                j += 1;
            }
            i = j;
        }
    }
    i
}

/// End of the word (letters, digits, `_`, and `.` between digits) starting at `i`.
fn scan_word(text: &str, i: usize) -> usize {
    let bytes = text.as_bytes();
    let mut end = i;
    while let Some(&b) = bytes.get(end) {
        if b.is_ascii_alphanumeric() || b == b'_' {
            end += 1;
        } else if b == b'.' && end > i && bytes.get(end + 1).is_some_and(u8::is_ascii_digit) {
            // `v1.5`: a dot followed by a digit stays inside the word
            end += 1;
        } else if b >= 0x80 {
            match text[end..].chars().next() {
                Some(c) if c.is_alphanumeric() => end += c.len_utf8(),
                _ => break,
            }
        } else {
            break;
        }
    }
    end
}

#[cfg(test)]
mod tests {
    use super::*;

    fn kinds(text: &str) -> Vec<Kind> {
        let mut out = Vec::new();
        tokenize(text, &mut out, &mut String::new());
        out.into_iter().map(|t| t.kind).collect()
    }

    fn nums(text: &str) -> Vec<f64> {
        kinds(text)
            .into_iter()
            .filter_map(|k| match k {
                Kind::Num { value, .. } => Some(value),
                _ => None,
            })
            .collect()
    }

    #[test]
    fn numbers_in_all_forms() {
        assert_eq!(
            nums("1 -2 +3 .5 -.25 1e3 2.5E-2 \u{2212}4 \u{2013}0.5"),
            vec![1.0, -2.0, 3.0, 0.5, -0.25, 1000.0, 0.025, -4.0, -0.5]
        );
    }

    #[test]
    fn digits_inside_words_are_not_numbers() {
        assert_eq!(
            nums("v1 = 5.0, c1 = 0.01, step2 x_3 0.5s 1st v1.5"),
            vec![5.0, 0.01]
        );
    }

    #[test]
    fn labels_list_markers_and_units_are_not_numbers() {
        assert_eq!(nums("Step 1: speed 5.0, curvature 0.01"), vec![5.0, 0.01]);
        assert_eq!(
            nums("1. 5.0, 0.01\n  2. 5.5 0.0\n3) 6.0 0.0"),
            vec![5.0, 0.01, 5.5, 0.0, 6.0, 0.0]
        );
        assert_eq!(
            nums("c1 = 0.01 1/m, v = 3 m/s, 0.2 rad/m, 0.1 /m, 0.3 m^-1"),
            vec![0.01, 3.0, 0.2, 0.1, 0.3]
        );
        // a fraction ending a sentence mid-line is still a number
        assert_eq!(nums("speed 5. then 4.5"), vec![5.0, 4.5]);
        // a curvature at the start of a line inside a list is not a list marker
        assert_eq!(
            nums("(5,\n0) (6,\n2), (7,\n3)\n"),
            vec![5.0, 0.0, 6.0, 2.0, 7.0, 3.0]
        );
    }

    #[test]
    fn numbers_describing_the_horizon_are_not_numbers() {
        assert_eq!(
            nums("Over the next 3 seconds at 0.5 s steps (6 steps): 5.0 0.01 6 pairs 2 Hz 4 sx"),
            vec![5.0, 0.01, 4.0]
        );
    }

    #[test]
    fn operators_and_signs() {
        use Kind::*;
        let k = kinds("7.2-0.5 7.2 - 0.5 7.2 -0.5 1/50 2*3");
        let ops: Vec<u8> = k
            .iter()
            .filter_map(|k| match k {
                Op { op, .. } => Some(*op),
                _ => None,
            })
            .collect();
        assert_eq!(ops, vec![b'-', b'-', b'/', b'*']);
        assert_eq!(
            nums("7.2-0.5 7.2 - 0.5 7.2 -0.5 1/50"),
            vec![7.2, 0.5, 7.2, 0.5, 7.2, -0.5, 1.0, 50.0]
        );
    }

    #[test]
    fn bad_numbers() {
        assert_eq!(
            kinds("3.7640.002 0001 05.5 0.5 0 00")
                .into_iter()
                .map(|k| match k {
                    Kind::Bad(b) => Some(b),
                    _ => None,
                })
                .collect::<Vec<_>>(),
            vec![
                Some(BadNum::Fused),
                Some(BadNum::LeadingZeros),
                Some(BadNum::LeadingZeros),
                None,
                None,
                Some(BadNum::LeadingZeros)
            ]
        );
    }

    #[test]
    fn doubled_signs_are_bad_numbers() {
        for text in ["--0.01", "+-0.5", "-+1", "\u{2212}-2", "-\u{2212}2"] {
            assert_eq!(kinds(text), vec![Kind::Bad(BadNum::DoubledSign)], "{text}");
        }
        // an operator between numbers, then a signed number, is no doubled sign
        assert_eq!(nums("5 - -3"), vec![5.0, -3.0]);
        assert_eq!(nums("x --"), Vec::<f64>::new());
    }

    #[test]
    fn trailing_dot_and_exponent_without_digits() {
        assert_eq!(nums("speed 5. then 3e"), vec![5.0]);
        assert_eq!(nums("(3-4)"), vec![3.0, 4.0]);
    }

    #[test]
    fn brackets_and_separators() {
        assert_eq!(
            kinds("([{,;}])"),
            vec![
                Kind::Open(b'('),
                Kind::Open(b'['),
                Kind::Open(b'{'),
                Kind::Comma,
                Kind::Semicolon,
                Kind::Close(b'}'),
                Kind::Close(b']'),
                Kind::Close(b')')
            ]
        );
    }

    #[test]
    fn non_finite_words() {
        let v = nums("nan NaN inf Infinity");
        assert!(v[0].is_nan() && v[1].is_nan());
        assert!(v[2].is_infinite() && v[3].is_infinite());
    }

    #[test]
    fn word_labels() {
        let labels: Vec<bool> = kinds("v1 speed Curvature κ2 the car")
            .into_iter()
            .map(|k| matches!(k, Kind::Word { label: true }))
            .collect();
        assert_eq!(labels, vec![true, true, true, true, false, false]);
    }

    #[test]
    fn ranges_tokenize_with_absolute_positions() {
        let text = "ab (1, 2) cd";
        let mut out = Vec::new();
        tokenize_range(text, 3, 9, &mut out, &mut String::new());
        assert_eq!(out.len(), 5);
        assert_eq!((out[1].pos, out[1].end), (4, 5));
    }

    #[test]
    fn unicode_and_junk_do_not_panic() {
        let junk = "\u{0}\u{FFFD}é漢字\u{2212}\u{2212}5 ((((";
        let v = nums(junk);
        assert_eq!(v, vec![-5.0]);
    }
}
