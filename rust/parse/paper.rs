//! The paper's own answer rules (`mode="paper"`), for reproducing its FE / FE corr columns.
//!
//! * **FE**: the answer, read as a Python literal (`ast.literal_eval`), is not a list
//!   of exactly `n` tuples of 2 numbers (`int` or `float`; not `bool`, not `complex`).
//! * **FE corr**: after that, fewer than `2n` numbers can be read by taking maximal
//!   runs of ASCII digits, `-` and `.` and keeping those of the form
//!   `-?digits(.digits)?`; the first `2n` of them form the pairs.
//!
//! The literal check is a recognizer for exactly the accepted shape, written to agree
//! with CPython 3.11's tokenizer and `ast.literal_eval` on it: redundant parentheses,
//! one unary sign per number, trailing commas, comments, line continuations inside
//! brackets, Python's numeric literals (`1_000`, `0x1F`, `1.`, `.5`, `1e-3`; `0001` is a
//! syntax error), at most 200 nested brackets, and the first/last-line indentation
//! rules of `eval` input after `literal_eval` strips leading spaces and tabs. Anything
//! else (a name, a string, `--5`, `5-0.5`, a list of lists, prose) makes the answer FE.
//! It is one linear pass with counters: no recursion, no backtracking.
//!
//! One deliberate difference from the paper's scripts: a number that does not fit a
//! float (`1e999`, a 400-digit integer) fails the answer, since NaN marks a failure.

/// CPython's tokenizer refuses more nested brackets than this (`MAXLEVEL`).
const MAX_NESTING: usize = 200;

/// Why the literal rule failed, with the byte offset where it was decided.
#[derive(Debug, Clone, PartialEq)]
pub struct NotLiteral {
    pub why: &'static str,
    pub pos: usize,
}

/// The answer as the paper reads it.
#[derive(Debug, Clone, PartialEq)]
pub enum PaperOutcome {
    /// A Python list of `n` (v, c) tuples.
    Literal,
    /// Not one (FE), but at least `2n` digit runs: the first `2n` were taken.
    DigitRuns { why: NotLiteral, found: usize },
    /// Neither (FE corr).
    Failed { why: NotLiteral, found: usize },
}

/// Apply the paper's two rules to `text`, writing `2n` values into `out` unless failed.
pub fn parse(text: &str, n: usize, out: &mut [f64], scratch: &mut String) -> PaperOutcome {
    debug_assert_eq!(out.len(), 2 * n);
    match literal(text, n, out, scratch) {
        Ok(()) => PaperOutcome::Literal,
        Err(why) => {
            let found = digit_runs(text, out);
            if found >= 2 * n {
                PaperOutcome::DigitRuns { why, found }
            } else {
                PaperOutcome::Failed { why, found }
            }
        }
    }
}

/// The FE corr rule: count the runs of `[0-9.-]` of the form `-?digits(.digits)?`,
/// writing the first `out.len()` of them into `out`. Returns how many there are.
pub fn digit_runs(text: &str, out: &mut [f64]) -> usize {
    let bytes = text.as_bytes();
    let mut found = 0;
    let mut i = 0;
    while i < bytes.len() {
        if !is_run_byte(bytes[i]) {
            i += 1;
            continue;
        }
        let start = i;
        while i < bytes.len() && is_run_byte(bytes[i]) {
            i += 1;
        }
        let run = &text[start..i];
        if is_plain_decimal(run.as_bytes()) {
            if found < out.len() {
                out[found] = run.parse::<f64>().unwrap_or(f64::NAN);
            }
            found += 1;
        }
    }
    found
}

fn is_run_byte(b: u8) -> bool {
    b.is_ascii_digit() || b == b'-' || b == b'.'
}

/// `-?digits(.digits)?`
fn is_plain_decimal(run: &[u8]) -> bool {
    let body = run.strip_prefix(b"-").unwrap_or(run);
    let (int, frac) = match body.iter().position(|&b| b == b'.') {
        Some(dot) => (&body[..dot], Some(&body[dot + 1..])),
        None => (body, None),
    };
    let digits = |s: &[u8]| !s.is_empty() && s.iter().all(u8::is_ascii_digit);
    digits(int) && frac.is_none_or(digits)
}

// ------------------------------------------------------------------ the literal rule

/// A Python token, as far as the accepted shape needs to tell them apart.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Tok {
    LPar,
    RPar,
    LSqb,
    RSqb,
    Comma,
    Sign(bool), // true for '-'
    /// An int or float literal; `int` tells `-0` (the int 0) from `-0.0`.
    Num {
        value: f64,
        int: bool,
    },
    End,
}

struct PyLexer<'a> {
    text: &'a str,
    bytes: &'a [u8],
    i: usize,
    depth: usize,
    scratch: &'a mut String,
}

type Step<T> = Result<T, NotLiteral>;

impl<'a> PyLexer<'a> {
    fn fail<T>(&self, why: &'static str) -> Step<T> {
        Err(NotLiteral { why, pos: self.i })
    }

    /// Skip a comment (from `#`) up to, not including, the end of its line.
    fn skip_comment(&mut self) -> Step<()> {
        while let Some(&b) = self.bytes.get(self.i) {
            match b {
                b'\n' | b'\r' => break,
                0 => return self.fail("a null byte"),
                _ => self.i += 1,
            }
        }
        Ok(())
    }

    fn skip_newline(&mut self) {
        if self.bytes.get(self.i) == Some(&b'\r') {
            self.i += 1;
            if self.bytes.get(self.i) == Some(&b'\n') {
                self.i += 1;
            }
        } else {
            self.i += 1;
        }
    }

    /// The prefix before the first token: `literal_eval` strips leading spaces and
    /// tabs; then blank or comment-only lines, and the first real line must not be
    /// indented.
    fn skip_prefix(&mut self) -> Step<()> {
        while matches!(self.bytes.get(self.i), Some(b' ' | b'\t')) {
            self.i += 1;
        }
        loop {
            let col = self.indentation();
            match self.bytes.get(self.i) {
                Some(b'#') => self.skip_comment()?,
                Some(b'\n' | b'\r') => self.skip_newline(),
                None => return Ok(()), // nothing at all: reported as a missing list
                Some(_) if col > 0 => return self.fail("an indented first line"),
                Some(_) => return Ok(()),
            }
        }
    }

    /// Skip the spaces, tabs and form feeds at the start of a line; return its column.
    fn indentation(&mut self) -> usize {
        let mut col = 0;
        while let Some(&b) = self.bytes.get(self.i) {
            match b {
                b' ' => col += 1,
                b'\t' => col = (col / 8 + 1) * 8,
                b'\x0c' => col = 0,
                _ => break,
            }
            self.i += 1;
        }
        col
    }

    /// After the list: the rest of its line, then only blank lines. A last line of
    /// spaces without a newline is an "unexpected indent" in CPython.
    fn check_suffix(&mut self) -> Step<()> {
        loop {
            match self.bytes.get(self.i) {
                Some(b' ' | b'\t' | b'\x0c') => self.i += 1,
                Some(b'#') => self.skip_comment()?,
                Some(b'\n' | b'\r') => {
                    self.skip_newline();
                    break;
                }
                None => return Ok(()),
                Some(_) => return self.fail("text after the list"),
            }
        }
        loop {
            let col = self.indentation();
            match self.bytes.get(self.i) {
                Some(b'#') => self.skip_comment()?,
                Some(b'\n' | b'\r') => self.skip_newline(),
                None if col > 0 => return self.fail("an indented last line"),
                None => return Ok(()),
                Some(_) => return self.fail("text after the list"),
            }
        }
    }

    /// The next token inside the literal (depth ≥ 1 once the first bracket is open).
    fn next(&mut self) -> Step<Tok> {
        loop {
            let Some(&b) = self.bytes.get(self.i) else {
                return Ok(Tok::End);
            };
            match b {
                b' ' | b'\t' | b'\x0c' => self.i += 1,
                b'\n' | b'\r' if self.depth > 0 => self.skip_newline(),
                b'#' if self.depth > 0 => self.skip_comment()?,
                b'\\' if self.depth > 0 => {
                    self.i += 1;
                    match self.bytes.get(self.i) {
                        Some(b'\n' | b'\r') => self.skip_newline(),
                        _ => return self.fail("a backslash not before a line break"),
                    }
                }
                _ => break,
            }
        }
        let b = self.bytes[self.i];
        let tok = match b {
            b'(' | b'[' => {
                if self.depth >= MAX_NESTING {
                    return self.fail("more than 200 nested brackets");
                }
                self.depth += 1;
                if b == b'(' {
                    Tok::LPar
                } else {
                    Tok::LSqb
                }
            }
            b')' | b']' => {
                self.depth = self.depth.saturating_sub(1);
                if b == b')' {
                    Tok::RPar
                } else {
                    Tok::RSqb
                }
            }
            b',' => Tok::Comma,
            b'-' | b'+' => Tok::Sign(b == b'-'),
            b'0'..=b'9' => return self.number(),
            b'.' if self.bytes.get(self.i + 1).is_some_and(u8::is_ascii_digit) => {
                return self.number()
            }
            _ if self.depth == 0 => return self.fail("text before the list"),
            _ => return self.fail("something other than brackets, commas and numbers"),
        };
        self.i += 1;
        Ok(tok)
    }

    /// A Python numeric literal starting at `self.i`.
    fn number(&mut self) -> Step<Tok> {
        let start = self.i;
        let bytes = self.bytes;
        if bytes[start] == b'0' {
            let radix = match bytes.get(start + 1) {
                Some(b'x' | b'X') => Some(16),
                Some(b'o' | b'O') => Some(8),
                Some(b'b' | b'B') => Some(2),
                _ => None,
            };
            if let Some(radix) = radix {
                self.i = start + 2;
                // (_? digit)+
                let mut any = false;
                loop {
                    let underscore = bytes.get(self.i) == Some(&b'_');
                    let at = self.i + usize::from(underscore);
                    match bytes.get(at).and_then(|&d| (d as char).to_digit(radix)) {
                        Some(_) => {
                            any = true;
                            self.i = at + 1;
                        }
                        None if underscore || !any => {
                            return self.fail("an invalid integer literal")
                        }
                        None => break,
                    }
                }
                self.end_of_number()?;
                let value = radix_value(&self.text[start + 2..self.i], radix);
                return Ok(Tok::Num { value, int: true });
            }
        }
        // decimal: digitpart? ('.' digitpart?)? exponent? — digitpart = digit (_? digit)*
        self.scratch.clear();
        let int_digits = self.digit_part()?;
        let mut is_int = true;
        if int_digits == 0 {
            self.scratch.push('0');
        }
        if bytes.get(self.i) == Some(&b'.') {
            is_int = false;
            self.i += 1;
            self.scratch.push('.');
            if self.digit_part()? == 0 {
                self.scratch.push('0');
            }
        }
        if matches!(bytes.get(self.i), Some(b'e' | b'E')) {
            self.i += 1;
            self.scratch.push('e');
            if let Some(&s @ (b'+' | b'-')) = bytes.get(self.i) {
                self.scratch.push(s as char);
                self.i += 1;
            }
            if !bytes.get(self.i).is_some_and(u8::is_ascii_digit) {
                return self.fail("an invalid decimal literal");
            }
            self.digit_part()?;
            is_int = false;
        }
        if matches!(bytes.get(self.i), Some(b'j' | b'J')) {
            return self.fail("a complex number");
        }
        self.end_of_number()?;
        if is_int
            && int_digits > 1
            && self.scratch.bytes().any(|d| d != b'0')
            && self.scratch.starts_with('0')
        {
            self.i = start;
            return self.fail("leading zeros in a decimal integer (0001)");
        }
        let value = self.scratch.parse::<f64>().unwrap_or(f64::NAN);
        Ok(Tok::Num { value, int: is_int })
    }

    /// `digit (_? digit)*`, appended to the scratch without underscores; returns the digit count.
    fn digit_part(&mut self) -> Step<usize> {
        let mut count = 0;
        loop {
            match self.bytes.get(self.i) {
                Some(&d) if d.is_ascii_digit() => {
                    self.scratch.push(d as char);
                    count += 1;
                    self.i += 1;
                }
                Some(b'_') if count > 0 => {
                    if !self.bytes.get(self.i + 1).is_some_and(u8::is_ascii_digit) {
                        return self.fail("an invalid decimal literal");
                    }
                    self.i += 1;
                }
                _ => return Ok(count),
            }
        }
    }

    /// A number may not run into a letter, digit, `_` or `.` (`5a`, `1.5.5`).
    fn end_of_number(&self) -> Step<()> {
        match self.text[self.i..].chars().next() {
            Some(c) if c.is_alphanumeric() || c == '_' || c == '.' => {
                self.fail("an invalid number literal")
            }
            _ => Ok(()),
        }
    }
}

/// The value of hexadecimal, octal or binary digits (underscores allowed), correctly rounded.
fn radix_value(digits: &str, radix: u32) -> f64 {
    let bits = radix.trailing_zeros(); // 16 → 4, 8 → 3, 2 → 1
    let mut mant: u128 = 0;
    let mut exp: i32 = 0;
    let mut sticky = false;
    for d in digits.chars().filter_map(|c| c.to_digit(radix)) {
        if mant >> (128 - bits) == 0 {
            mant = (mant << bits) | u128::from(d);
        } else {
            exp += bits as i32;
            sticky |= d != 0;
        }
    }
    let width = 128 - mant.leading_zeros();
    if width <= 53 {
        return mant as f64 * 2f64.powi(exp);
    }
    let shift = width - 53;
    let mut top = mant >> shift;
    let rem = mant & ((1u128 << shift) - 1);
    let half = 1u128 << (shift - 1);
    if rem > half || (rem == half && (sticky || top & 1 == 1)) {
        top += 1;
    }
    top as f64 * 2f64.powi(exp + shift as i32)
}

/// The FE rule: `text` is a Python list literal of exactly `n` 2-tuples of numbers.
fn literal(text: &str, n: usize, out: &mut [f64], scratch: &mut String) -> Step<()> {
    if text.as_bytes().contains(&0) {
        return Err(NotLiteral {
            why: "a null byte",
            pos: text.as_bytes().iter().position(|&b| b == 0).unwrap_or(0),
        });
    }
    let mut lx = PyLexer {
        text,
        bytes: text.as_bytes(),
        i: 0,
        depth: 0,
        scratch,
    };
    lx.skip_prefix()?;
    // ( * [
    let mut outer = 0usize;
    loop {
        match lx.next()? {
            Tok::LPar => outer += 1,
            Tok::LSqb => break,
            Tok::End => return lx.fail("no list"),
            _ => return lx.fail("not a list"),
        }
    }
    let mut count = 0usize;
    let mut tok = lx.next()?;
    loop {
        if tok == Tok::RSqb {
            break;
        }
        // an element: must be a 2-tuple of numbers
        let (v, c, after) = tuple(&mut lx, tok)?;
        if count < n {
            out[2 * count] = v;
            out[2 * count + 1] = c;
        }
        count += 1;
        match after {
            Tok::RSqb => break,
            Tok::Comma => tok = lx.next()?,
            Tok::End => return lx.fail("an unclosed list"),
            _ => return lx.fail("expected ',' or ']' after a tuple"),
        }
    }
    for _ in 0..outer {
        if lx.next()? != Tok::RPar {
            return lx.fail("not a list");
        }
    }
    lx.check_suffix()?;
    if count != n {
        return Err(NotLiteral {
            why: if count < n {
                "fewer tuples than actions"
            } else {
                "more tuples than actions"
            },
            pos: text.len(),
        });
    }
    Ok(())
}

/// Count `(` tokens starting with `tok`; returns (count, first other token).
fn count_lpar(lx: &mut PyLexer<'_>, mut tok: Tok) -> Step<(usize, Tok)> {
    let mut k = 0;
    while tok == Tok::LPar {
        k += 1;
        tok = lx.next()?;
    }
    Ok((k, tok))
}

/// After the parentheses before a number: `[sign '('*] NUM`. Returns (value, parens after the sign).
fn signed_number(lx: &mut PyLexer<'_>, tok: Tok) -> Step<(f64, usize)> {
    let (negative, tok) = match tok {
        Tok::Sign(neg) => (Some(neg), lx.next()?),
        other => (None, other),
    };
    let (inner, tok) = match negative {
        Some(_) => count_lpar(lx, tok)?,
        None => (0, tok),
    };
    match tok {
        Tok::Num { value, int } => {
            let value = match negative {
                // `-0` is the int 0: no negative zero
                Some(true) if !(int && value == 0.0) => -value,
                _ => value,
            };
            Ok((value, inner))
        }
        Tok::Sign(_) => lx.fail("two signs on a number"),
        Tok::End => lx.fail("an unclosed list"),
        _ => lx.fail("a tuple item that is not a number"),
    }
}

/// Count `)` tokens; returns (count, first other token).
fn count_rpar(lx: &mut PyLexer<'_>) -> Step<(usize, Tok)> {
    let mut m = 0;
    loop {
        match lx.next()? {
            Tok::RPar => m += 1,
            other => return Ok((m, other)),
        }
    }
}

/// One list element starting at `tok`: `(v, c)`, with any redundant parentheses.
/// Returns the values and the token after the element.
fn tuple(lx: &mut PyLexer<'_>, tok: Tok) -> Step<(f64, f64, Tok)> {
    let (k, tok) = count_lpar(lx, tok)?;
    if k == 0 {
        return lx.fail("a list item that is not a tuple");
    }
    let (v, b) = signed_number(lx, tok)?;
    let (m, tok) = count_rpar(lx)?;
    if tok == Tok::End {
        return lx.fail("an unclosed list");
    }
    if tok != Tok::Comma || m < b || m - b >= k {
        return lx.fail("a list item that is not a tuple of 2 numbers");
    }
    // the parentheses that belong to the tuple itself (and redundant ones around it)
    let t = k - (m - b);
    let first = lx.next()?;
    let (a2, tok) = count_lpar(lx, first)?;
    let (c, b2) = signed_number(lx, tok)?;
    let (m2, tok) = count_rpar(lx)?;
    if tok == Tok::End {
        return lx.fail("an unclosed list");
    }
    let after = if m2 == a2 + b2 + t {
        tok
    } else if m2 == a2 + b2 && tok == Tok::Comma {
        // a trailing comma inside the tuple, then exactly the tuple's parentheses
        let (r, after) = count_rpar(lx)?;
        if r != t {
            return lx.fail("a list item that is not a tuple of 2 numbers");
        }
        after
    } else {
        return lx.fail("a list item that is not a tuple of 2 numbers");
    };
    Ok((v, c, after))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn run(text: &str) -> (PaperOutcome, Vec<f64>) {
        let mut out = vec![f64::NAN; 12];
        let outcome = parse(text, 6, &mut out, &mut String::new());
        (outcome, out)
    }

    fn is_literal(text: &str) -> bool {
        run(text).0 == PaperOutcome::Literal
    }

    const SIX: &str =
        "[(5.0, 0.01), (5.5, 0.0), (6.0, -0.02), (6.5, 0.0), (7.0, 0.0), (7.5, 0.003)]";

    #[test]
    fn the_requested_format_is_a_literal() {
        let (outcome, out) = run(SIX);
        assert_eq!(outcome, PaperOutcome::Literal);
        assert_eq!(
            out,
            vec![5.0, 0.01, 5.5, 0.0, 6.0, -0.02, 6.5, 0.0, 7.0, 0.0, 7.5, 0.003]
        );
    }

    #[test]
    fn python_literal_variants() {
        let six = |pair: &str| format!("[{}]", [pair; 6].join(", "));
        for ok in [
            six("(5, 0)"),
            six("((5), (0))"),
            six("((5, 0))"),
            six("(-(5), +0.5)"),
            six("(- 5, 0,)"),
            six("(0x1F, 0b1)"),
            six("(1_000, 1.e5)"),
            six("(00, 00.5)"),
            six("(.5, 5.)"),
            format!("([{}])", ["(1, 2)"; 6].join(",")),
            format!("[{},]", ["(1, 2)"; 6].join(",")),
            format!("  {SIX}\n\n"),
            format!("\n# comment\n{SIX} # done\n"),
            format!("[(1,\n 2), # c\n{}]", ["(1, 2)"; 5].join(",\\\n")),
        ] {
            assert!(is_literal(&ok), "{ok}");
        }
        for fe in [
            six("[5, 0]"),
            six("(5, 0, 1)"),
            six("((5, 0),)"),
            six("(--5, 0)"),
            six("(5-0.5, 0)"),
            six("(0001, 0)"),
            six("(1j, 0)"),
            six("(True, 0)"),
            six("(1__0, 0)"),
            six("(5a, 0)"),
            six("(1.5.5, 0)"),
            six("(5, 0)(1, 2)"),
            format!("[{}]", ["(1, 2)"; 5].join(",")),
            format!("[{}]", ["(1, 2)"; 7].join(",")),
            format!("{SIX},"),
            format!("{SIX} and more"),
            format!("\n  {SIX}"),
            format!("{SIX}\n "),
            format!("```\n{SIX}\n```"),
            SIX.replace("-0.02", "\u{2212}0.02"),
            SIX[..SIX.len() - 1].to_owned(),
        ] {
            assert!(!is_literal(&fe), "{fe}");
        }
    }

    #[test]
    fn negative_zero_follows_python() {
        let six = |pair: &str| format!("[{}]", [pair; 6].join(", "));
        let (_, out) = run(&six("(-0, -0.0)"));
        assert!(out[0] == 0.0 && out[0].is_sign_positive());
        assert!(out[1] == 0.0 && out[1].is_sign_negative());
    }

    #[test]
    fn nesting_limit_is_cpythons() {
        let deep = |d: usize| {
            format!(
                "[({}5{}, 0), {}]",
                "(".repeat(d),
                ")".repeat(d),
                ["(1, 2)"; 5].join(",")
            )
        };
        assert!(is_literal(&deep(198)));
        assert!(!is_literal(&deep(199)));
    }

    #[test]
    fn radix_values_round_correctly() {
        assert_eq!(radix_value("ff", 16), 255.0);
        assert_eq!(radix_value("1_0", 2), 2.0);
        // 2^53 + 1 rounds to even (2^53); 2^53 + 3 rounds up to 2^53 + 4
        assert_eq!(radix_value("20000000000001", 16), 9007199254740992.0);
        assert_eq!(radix_value("20000000000003", 16), 9007199254740996.0);
        assert_eq!(radix_value(&"f".repeat(40), 16), 2f64.powi(160));
        assert!(radix_value(&"f".repeat(300), 16).is_infinite());
    }

    #[test]
    fn digit_runs_follow_the_paper() {
        let mut out = vec![0.0; 4];
        // `3.7640.002`, `7.2-0.5` and `5.` are not of the form; `v1` gives 1; `−` is not `-`
        assert_eq!(
            digit_runs("v1 (3.7640.002) 7.2-0.5 5. 0001 -0.5 \u{2212}2", &mut out),
            4
        );
        assert_eq!(out, vec![1.0, 1.0, -0.5, 2.0]);
    }

    #[test]
    fn fe_then_digit_runs() {
        let text = format!("Sure: {SIX}");
        let (outcome, out) = run(&text);
        assert!(matches!(outcome, PaperOutcome::DigitRuns { found: 12, .. }));
        assert_eq!(out[5], -0.02);
        let (outcome, _) = run("[(5.0, 0.01)]");
        assert!(matches!(outcome, PaperOutcome::Failed { found: 2, .. }));
    }

    #[test]
    fn hostile_inputs_terminate() {
        for text in [
            "9".repeat(1 << 20),
            "[".repeat(100_000),
            "(".repeat(100_000) + "1",
            "-".repeat(100_000),
            "\u{0}".repeat(10),
            "1e".to_owned() + &"9".repeat(10_000),
        ] {
            let _ = run(&text);
        }
    }
}
