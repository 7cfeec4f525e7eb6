//! A single-pass, allocation-light tokenizer for model answers.
//!
//! It never backtracks and never recurses, so any input (binary junk, megabytes
//! of digits, deeply nested brackets) is scanned in linear time. It knows just
//! enough to find numbers and brackets:
//!
//! * a **number** is `[sign] digits [. digits] [e [sign] digits]` (or `.5`),
//!   where the sign may be `-`, `+` or the unicode minus `−`; the words `nan`,
//!   `inf` and `infinity` are numbers too (non-finite, so they never pass);
//! * a number glued to a word (`v1`, `step2`, `0.5s`, `c_1`) is part of that
//!   word, not a number;
//! * a **label** is not a number either: `Step 1:` (a number followed by `:`),
//!   a list marker `2. ` at the start of a line, or a unit `1/m`;
//! * brackets `(`/`[` and `)`/`]`, commas and semicolons are tokens; anything
//!   else is `Other`.

/// A token and its byte offset in the answer.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Token {
    pub kind: Kind,
    pub pos: usize,
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Kind {
    /// A number; `plain` is false for the unicode minus and for `nan`/`inf` words.
    Num {
        value: f64,
        plain: bool,
    },
    Open(u8),
    Close(u8),
    Comma,
    Semicolon,
    Other,
}

const UNICODE_MINUS: char = '\u{2212}';

fn is_word_char(c: char) -> bool {
    c.is_alphanumeric() || c == '_'
}

/// Tokenize `text` into `out` (cleared first). `scratch` is reused for number text.
pub fn tokenize(text: &str, out: &mut Vec<Token>, scratch: &mut String) {
    out.clear();
    let bytes = text.as_bytes();
    let mut i = 0;
    // whether the previous character (if any) belongs to a word
    let mut prev_word = false;
    // whether only whitespace precedes on the current line
    let mut line_start = true;
    while i < bytes.len() {
        let b = bytes[i];
        let (c, width) = if b < 0x80 {
            (b as char, 1)
        } else {
            // `text` is valid UTF-8, so a char starts here
            let c = text[i..].chars().next().unwrap_or('\u{FFFD}');
            (c, c.len_utf8())
        };
        if c.is_whitespace() {
            prev_word = false;
            line_start |= c == '\n';
            i += width;
            continue;
        }
        let start = i;
        let at_line_start = line_start;
        line_start = false;
        // numbers, possibly signed
        let signed = matches!(c, '-' | '+' | UNICODE_MINUS) && !prev_word;
        let num_start = if signed { i + width } else { i };
        if (signed || !prev_word) && starts_number(bytes, num_start) {
            let end = scan_number(bytes, num_start);
            let glued = text[end..].chars().next().is_some_and(is_word_char);
            if !glued
                && (is_label(bytes, end, at_line_start && !signed) || describes_horizon(text, end))
            {
                out.push(Token {
                    kind: Kind::Other,
                    pos: start,
                });
                prev_word = true;
                line_start = false;
                i = end;
                continue;
            }
            if glued {
                // e.g. `0.5s`, `1st`: part of a word
                let end = scan_word(text, end);
                out.push(Token {
                    kind: Kind::Other,
                    pos: start,
                });
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
            out.push(Token {
                kind: Kind::Num {
                    value,
                    plain: c != UNICODE_MINUS,
                },
                pos: start,
            });
            // a sign right after a number is a hyphen (`3-4`), not a sign
            prev_word = true;
            i = end;
            continue;
        }
        if is_word_char(c) {
            let end = scan_word(text, i);
            let word = &text[i..end];
            let kind = if word.eq_ignore_ascii_case("nan") {
                Kind::Num {
                    value: f64::NAN,
                    plain: false,
                }
            } else if word.eq_ignore_ascii_case("inf") || word.eq_ignore_ascii_case("infinity") {
                Kind::Num {
                    value: f64::INFINITY,
                    plain: false,
                }
            } else {
                Kind::Other
            };
            out.push(Token { kind, pos: start });
            prev_word = true;
            i = end;
            continue;
        }
        let kind = match c {
            '(' | '[' => Kind::Open(b),
            ')' | ']' => Kind::Close(b),
            ',' => Kind::Comma,
            ';' => Kind::Semicolon,
            _ => Kind::Other,
        };
        out.push(Token { kind, pos: start });
        prev_word = false;
        i += width;
    }
}

/// Whether the number ending at `end` is a label: `1:`, a list marker `1. ` at
/// the start of a line (`list_position`), or a unit such as `1/m`.
fn is_label(bytes: &[u8], end: usize, list_position: bool) -> bool {
    match bytes.get(end) {
        Some(b':') => true,
        Some(b'.') => list_position && bytes.get(end + 1).is_none_or(u8::is_ascii_whitespace),
        Some(b'/') => bytes.get(end + 1).is_some_and(u8::is_ascii_alphabetic),
        _ => false,
    }
}

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

/// Whether the number ending at `end` is followed (after spaces) by a horizon word.
fn describes_horizon(text: &str, end: usize) -> bool {
    let rest = text[end..].trim_start_matches([' ', '\t']);
    // at most the longest horizon word plus one character is looked at
    let mut word_end = None;
    for (i, c) in rest.char_indices().take(10) {
        if !is_word_char(c) {
            word_end = Some(i);
            break;
        }
    }
    let word = match word_end {
        Some(i) => &rest[..i],
        None if rest.chars().nth(9).is_none() => rest,
        None => return false,
    };
    HORIZON_WORDS.iter().any(|w| w.eq_ignore_ascii_case(word))
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
    let mut end = i;
    let mut chars = text[i..].char_indices().peekable();
    while let Some((off, c)) = chars.next() {
        if is_word_char(c) {
            end = i + off + c.len_utf8();
        } else if c == '.' && end == i + off {
            // `v1.5`: a dot followed by a digit stays inside the word
            match chars.peek() {
                Some((_, d)) if d.is_ascii_digit() => end = i + off + 1,
                _ => break,
            }
        } else {
            break;
        }
    }
    end.max(i)
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
            nums("1 -2 +3 .5 -.25 1e3 2.5E-2 \u{2212}4"),
            vec![1.0, -2.0, 3.0, 0.5, -0.25, 1000.0, 0.025, -4.0]
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
            nums("1. 5.0, 0.01\n  2. 5.5 0.0"),
            vec![5.0, 0.01, 5.5, 0.0]
        );
        assert_eq!(nums("c1 = 0.01 1/m, v = 3 m/s"), vec![0.01, 3.0]);
        // a fraction ending a sentence mid-line is still a number
        assert_eq!(nums("speed 5. then 4.5"), vec![5.0, 4.5]);
    }

    #[test]
    fn numbers_describing_the_horizon_are_not_numbers() {
        assert_eq!(
            nums("Over the next 3 seconds at 0.5 s steps (6 steps): 5.0 0.01 6 pairs 2 Hz 4 sx"),
            vec![5.0, 0.01, 4.0]
        );
    }

    #[test]
    fn trailing_dot_and_exponent_without_digits() {
        assert_eq!(nums("speed 5. then 3e"), vec![5.0]);
        assert_eq!(nums("(3-4)"), vec![3.0, 4.0]);
    }

    #[test]
    fn brackets_and_separators() {
        assert_eq!(
            kinds("([,;])"),
            vec![
                Kind::Open(b'('),
                Kind::Open(b'['),
                Kind::Comma,
                Kind::Semicolon,
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
    fn unicode_and_junk_do_not_panic() {
        let junk = "\u{0}\u{FFFD}é漢字\u{2212}\u{2212}5 ((((";
        let v = nums(junk);
        assert_eq!(v, vec![-5.0]);
    }
}
