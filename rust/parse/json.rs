//! `mode="json"`: the answer of a provider's structured output.
//!
//! The whole answer (surrounding whitespace and one Markdown code fence allowed) is
//! the JSON object `{"actions": [[v1, c1], …, [vn, cn]]}`: that one key, exactly `n`
//! pairs, JSON numbers (no `+`, no leading zeros, no `.5`). One linear pass.

/// Why the answer is not the object; `truncated` when the text ended inside it.
#[derive(Debug, Clone, PartialEq)]
pub struct JsonError {
    pub reason: String,
    pub truncated: bool,
}

struct Reader<'a> {
    text: &'a str,
    bytes: &'a [u8],
    i: usize,
}

impl Reader<'_> {
    fn ws(&mut self) {
        while matches!(self.bytes.get(self.i), Some(b' ' | b'\t' | b'\n' | b'\r')) {
            self.i += 1;
        }
    }

    fn fail<T>(&self, expected: &str) -> Result<T, JsonError> {
        match self.text.get(self.i..).and_then(|rest| rest.chars().next()) {
            None => Err(JsonError {
                reason: "truncated".to_owned(),
                truncated: true,
            }),
            Some(_) => {
                let found: String = self.text[self.i..].chars().take(12).collect();
                Err(JsonError {
                    reason: format!(
                        "not a JSON object {{\"actions\": [[v, c], …]}}: expected {expected} but found {found:?} at position {}",
                        self.i
                    ),
                    truncated: false,
                })
            }
        }
    }

    fn expect(&mut self, byte: u8, what: &str) -> Result<(), JsonError> {
        self.ws();
        if self.bytes.get(self.i) == Some(&byte) {
            self.i += 1;
            Ok(())
        } else {
            self.fail(what)
        }
    }

    fn expect_str(&mut self, s: &str) -> Result<(), JsonError> {
        self.ws();
        let end = self.i + s.len();
        if self.bytes.get(self.i..end) == Some(s.as_bytes()) {
            self.i = end;
            return Ok(());
        }
        // a prefix of `s` up to the end of the text is a cut-off answer
        let rest = &self.bytes[self.i..];
        if rest.len() < s.len() && s.as_bytes().starts_with(rest) {
            self.i = self.bytes.len();
        }
        self.fail(s)
    }

    /// `-?(0|[1-9][0-9]*)(\.[0-9]+)?([eE][+-]?[0-9]+)?`
    fn number(&mut self) -> Result<f64, JsonError> {
        self.ws();
        let start = self.i;
        let b = self.bytes;
        let digits = |i: &mut usize| {
            let s = *i;
            while b.get(*i).is_some_and(u8::is_ascii_digit) {
                *i += 1;
            }
            *i - s
        };
        let mut i = self.i;
        if b.get(i) == Some(&b'-') {
            i += 1;
        }
        let int_start = i;
        let int = digits(&mut i);
        if int == 0 || (int > 1 && b[int_start] == b'0') {
            self.i = if i >= b.len() { i } else { int_start };
            return self.fail("a JSON number");
        }
        if b.get(i) == Some(&b'.') {
            i += 1;
            if digits(&mut i) == 0 {
                self.i = i;
                return self.fail("digits after '.'");
            }
        }
        if matches!(b.get(i), Some(b'e' | b'E')) {
            i += 1;
            if matches!(b.get(i), Some(b'+' | b'-')) {
                i += 1;
            }
            if digits(&mut i) == 0 {
                self.i = i;
                return self.fail("exponent digits");
            }
        }
        self.i = i;
        Ok(self.text[start..i].parse::<f64>().unwrap_or(f64::NAN))
    }
}

/// The text inside one code fence (```` ```json … ``` ````), or the trimmed text.
fn unfence(text: &str) -> &str {
    let t = text.trim_matches(|c: char| c.is_ascii_whitespace());
    let Some(body) = t.strip_prefix("```") else {
        return t;
    };
    // the info string (`json`) runs to the end of the first line
    let body = match body.find('\n') {
        Some(nl)
            if body[..nl]
                .chars()
                .all(|c| c.is_ascii_alphanumeric() || c.is_ascii_whitespace()) =>
        {
            &body[nl + 1..]
        }
        _ => body,
    };
    body.strip_suffix("```").unwrap_or(body)
}

/// Read `text` as `{"actions": [[v, c] × n]}` into `out` (`2n` values).
pub fn parse(text: &str, n: usize, out: &mut [f64]) -> Result<(), JsonError> {
    let inner = unfence(text);
    let mut r = Reader {
        text: inner,
        bytes: inner.as_bytes(),
        i: 0,
    };
    r.expect(b'{', "'{'")?;
    r.expect_str("\"actions\"")?;
    r.expect(b':', "':'")?;
    r.expect(b'[', "'['")?;
    let mut count = 0;
    r.ws();
    if r.bytes.get(r.i) == Some(&b']') {
        r.i += 1;
    } else {
        loop {
            r.expect(b'[', "'[' (a pair)")?;
            let v = r.number()?;
            r.expect(b',', "','")?;
            let c = r.number()?;
            r.expect(b']', "']' after a pair")?;
            if count < n {
                out[2 * count] = v;
                out[2 * count + 1] = c;
            }
            count += 1;
            r.ws();
            match r.bytes.get(r.i) {
                Some(b',') => r.i += 1,
                Some(b']') => {
                    r.i += 1;
                    break;
                }
                _ => return r.fail("',' or ']'"),
            }
        }
    }
    r.expect(b'}', "'}'")?;
    r.ws();
    if r.i < r.bytes.len() {
        return r.fail("the end of the answer");
    }
    if count != n {
        return Err(JsonError {
            reason: format!("\"actions\" has {count} pair(s); expected {n}"),
            truncated: false,
        });
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn run(text: &str) -> Result<Vec<f64>, JsonError> {
        let mut out = vec![f64::NAN; 4];
        parse(text, 2, &mut out).map(|()| out)
    }

    #[test]
    fn the_object_with_fences_and_whitespace() {
        let want = vec![5.0, 0.01, -1.5, 0.0];
        assert_eq!(
            run(r#"{"actions": [[5.0, 0.01], [-1.5, 0]]}"#).unwrap(),
            want
        );
        assert_eq!(
            run("```json\n{ \"actions\" : [ [5.0,0.01] ,\n [-1.5, 0e0] ] }\n```\n").unwrap(),
            want
        );
    }

    #[test]
    fn everything_else_fails() {
        for bad in [
            r#"{"actions": [[5.0, 0.01]]}"#,
            r#"{"actions": [[5.0, 0.01], [1, 2], [3, 4]]}"#,
            r#"{"actions": [[05.0, 0.01], [1, 2]]}"#,
            r#"{"actions": [[+5.0, 0.01], [1, 2]]}"#,
            r#"{"actions": [[.5, 0.01], [1, 2]]}"#,
            r#"{"actions": [(5, 0.01), [1, 2]]}"#,
            r#"{"speeds": [[5, 0.01], [1, 2]]}"#,
            r#"{"actions": [[5, 0.01], [1, 2]]} thanks"#,
            r#"[[5, 0.01], [1, 2]]"#,
        ] {
            let err = run(bad).unwrap_err();
            assert!(!err.truncated, "{bad}: {err:?}");
        }
    }

    #[test]
    fn cut_off_is_truncated() {
        for cut in [
            r#"{"actions": [[5.0, 0.01], [1, 2"#,
            r#"{"actions": [[5.0, 0.01], [1, -"#,
            r#"{"actio"#,
            "{",
        ] {
            let err = run(cut).unwrap_err();
            assert!(err.truncated, "{cut}: {err:?}");
            assert_eq!(err.reason, "truncated");
        }
    }
}
