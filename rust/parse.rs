//! Parsing a model's stage-3 answer into `n` (speed, curvature) actions.
//!
//! * **strict**: after trimming, the whole answer is `[(v, c), …]` with exactly
//!   `n` pairs of finite plain numbers (round or square inner brackets).
//! * **lenient**: the strict format, else the actions found in the answer's
//!   structure (see [`crate::lenient`]).
//! * **paper**: the paper's own FE / FE corr rules (see [`crate::paper`]).
//! * **json**: a provider's structured output `{"actions": [[v, c], …]}` (see [`crate::json`]).
//!
//! Strict, lenient and json answers then pass a plausibility gate ([`Limits`]).
//! Every answer gets a [`Status`], a [`Failure`] kind and, unless plainly `Ok`, a short reason.

use crate::error::{CoreError, CoreResult};
use crate::lexer::{tokenize, Kind, Token};
use crate::{json, paper};

/// How an answer parsed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u8)]
pub enum Status {
    /// The strict format was met (in paper mode: the paper's literal rule).
    Ok = 0,
    /// Only the lenient reading found the actions (paper mode: the digit-run rule).
    Corrected = 1,
    /// No usable actions.
    Failed = 2,
}

impl Status {
    pub fn as_str(self) -> &'static str {
        match self {
            Status::Ok => "ok",
            Status::Corrected => "corrected",
            Status::Failed => "failed",
        }
    }
}

/// Why an answer failed (`None` when it did not).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u8)]
pub enum Failure {
    None = 0,
    /// The answer ends inside the list, a pair or a reasoning block.
    Truncated = 1,
    /// Read fine, but a speed or curvature is outside the [`Limits`].
    Implausible = 2,
    /// Everything else: no list, malformed pairs, non-finite values, empty answers.
    Format = 3,
}

impl Failure {
    pub const NAMES: &'static [&'static str] = &["", "truncated", "implausible", "format"];

    pub fn as_str(self) -> &'static str {
        Self::NAMES[self as usize]
    }
}

/// Which rules to apply.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Mode {
    Strict,
    Lenient,
    Paper,
    Json,
}

impl Mode {
    pub const NAMES: &'static [&'static str] = &["strict", "lenient", "paper", "json"];

    pub fn from_name(name: &str) -> CoreResult<Self> {
        match name {
            "strict" => Ok(Mode::Strict),
            "lenient" => Ok(Mode::Lenient),
            "paper" => Ok(Mode::Paper),
            "json" => Ok(Mode::Json),
            _ => Err(CoreError::UnknownName {
                kind: "parse mode",
                name: name.to_owned(),
                allowed: Self::NAMES,
            }),
        }
    }
}

/// Plausibility limits: speeds in `speed` (m/s, inclusive), `|curvature| <= curvature` (1/m).
/// `None` disables a limit. Paper mode never applies them.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Limits {
    pub speed: Option<(f64, f64)>,
    pub curvature: Option<f64>,
}

impl Limits {
    /// [−10, 50] m/s and |κ| ≤ 1 /m (a turning radius of at least 1 m).
    pub const DEFAULT: Limits = Limits {
        speed: Some((-10.0, 50.0)),
        curvature: Some(1.0),
    };
    pub const NONE: Limits = Limits {
        speed: None,
        curvature: None,
    };

    /// Checked limits: finite, `lo < hi`, `curvature > 0`.
    pub fn new(speed: Option<(f64, f64)>, curvature: Option<f64>) -> CoreResult<Self> {
        if let Some((lo, hi)) = speed {
            if !(lo.is_finite() && hi.is_finite() && lo < hi) {
                return Err(CoreError::Argument(format!(
                    "speed_range must be two finite numbers (lo, hi) with lo < hi, got ({lo}, {hi})"
                )));
            }
        }
        if let Some(k) = curvature {
            if !(k.is_finite() && k > 0.0) {
                return Err(CoreError::Argument(format!(
                    "max_abs_curvature must be a finite number > 0, got {k}"
                )));
            }
        }
        Ok(Limits { speed, curvature })
    }

    /// The first value outside the limits, as a reason naming its step.
    fn check(&self, values: &[f64]) -> Option<String> {
        for (step, pair) in values.chunks_exact(2).enumerate() {
            let (v, c) = (pair[0], pair[1]);
            if let Some((lo, hi)) = self.speed {
                if !(lo..=hi).contains(&v) {
                    return Some(format!(
                        "speed {v} at step {} outside [{lo}, {hi}] m/s",
                        step + 1
                    ));
                }
            }
            if let Some(k) = self.curvature {
                if c.abs() > k {
                    return Some(format!(
                        "curvature {c} at step {} outside [-{k}, {k}] 1/m",
                        step + 1
                    ));
                }
            }
        }
        None
    }
}

/// The outcome for one answer besides its values.
#[derive(Debug, Clone, PartialEq)]
pub struct Outcome {
    pub status: Status,
    pub failure: Failure,
    pub reason: String,
}

impl Outcome {
    fn ok() -> Self {
        Outcome {
            status: Status::Ok,
            failure: Failure::None,
            reason: String::new(),
        }
    }

    fn corrected(reason: String) -> Self {
        Outcome {
            status: Status::Corrected,
            failure: Failure::None,
            reason,
        }
    }

    fn failed(failure: Failure, reason: String) -> Self {
        Outcome {
            status: Status::Failed,
            failure,
            reason,
        }
    }
}

/// The outcome for one answer: `values` holds `2n` numbers (v1, c1, v2, c2, …) unless failed.
#[derive(Debug, Clone, PartialEq)]
pub struct Parsed {
    pub status: Status,
    pub failure: Failure,
    pub values: Option<Vec<f64>>,
    pub reason: String,
}

/// Reusable buffers, so that parsing a batch allocates once.
#[derive(Default)]
pub struct Parser {
    tokens: Vec<Token>,
    scratch: String,
}

impl Parser {
    pub fn new() -> Self {
        Self::default()
    }

    /// Parse one answer for `n` actions. The values are written into `out` (length `2n`,
    /// NaN where failed).
    pub fn parse_into(
        &mut self,
        text: &str,
        n: usize,
        mode: Mode,
        limits: &Limits,
        out: &mut [f64],
    ) -> Outcome {
        debug_assert_eq!(out.len(), 2 * n);
        let outcome = match mode {
            Mode::Paper => self.paper(text, n, out),
            Mode::Json => match json::parse(text, n, out) {
                Ok(()) => gate(Outcome::ok(), limits, out),
                Err(e) => Outcome::failed(
                    if e.truncated {
                        Failure::Truncated
                    } else {
                        Failure::Format
                    },
                    e.reason,
                ),
            },
            Mode::Strict | Mode::Lenient => self.strict_or_lenient(text, n, mode, out),
        };
        let outcome = match (outcome.status, mode) {
            (Status::Failed, _) => outcome,
            (_, Mode::Paper | Mode::Json) => outcome,
            _ => gate(outcome, limits, out),
        };
        if outcome.status == Status::Failed {
            out.fill(f64::NAN);
        }
        outcome
    }

    fn paper(&mut self, text: &str, n: usize, out: &mut [f64]) -> Outcome {
        let outcome = match paper::parse(text, n, out, &mut self.scratch) {
            paper::PaperOutcome::Literal => Outcome::ok(),
            paper::PaperOutcome::DigitRuns { why, found } => Outcome::corrected(format!(
                "not a Python list of {n} (v, c) tuples ({} at position {}); took the first {} of {found} numbers",
                why.why,
                why.pos,
                2 * n
            )),
            paper::PaperOutcome::Failed { why, found } => {
                return Outcome::failed(
                    Failure::Format,
                    format!(
                        "not a Python list of {n} (v, c) tuples ({} at position {}), and only {found} number(s) for {} values",
                        why.why,
                        why.pos,
                        2 * n
                    ),
                )
            }
        };
        finite(outcome, out)
    }

    fn strict_or_lenient(&mut self, text: &str, n: usize, mode: Mode, out: &mut [f64]) -> Outcome {
        tokenize(text, &mut self.tokens, &mut self.scratch);
        if self.tokens.is_empty() {
            return Outcome::failed(Failure::Format, "empty answer".to_owned());
        }
        let strict_err = match strict(&self.tokens, text, n, out) {
            Ok(()) => return finite(Outcome::ok(), out),
            Err(reason) => reason,
        };
        if mode == Mode::Strict {
            return Outcome::failed(Failure::Format, strict_err);
        }
        match lenient(&self.tokens, n, out) {
            Ok(()) => finite(Outcome::corrected(strict_err), out),
            Err(reason) => Outcome::failed(Failure::Format, reason),
        }
    }

    /// Convenience wrapper returning a [`Parsed`].
    pub fn parse(&mut self, text: &str, n: usize, mode: Mode, limits: &Limits) -> Parsed {
        let mut values = vec![f64::NAN; 2 * n];
        let o = self.parse_into(text, n, mode, limits, &mut values);
        Parsed {
            status: o.status,
            failure: o.failure,
            values: (o.status != Status::Failed).then_some(values),
            reason: o.reason,
        }
    }
}

/// Fail an outcome whose values are not all finite.
fn finite(outcome: Outcome, values: &[f64]) -> Outcome {
    match values.iter().position(|v| !v.is_finite()) {
        None => outcome,
        Some(idx) => Outcome::failed(
            Failure::Format,
            format!(
                "action {} has a non-finite {}",
                idx / 2 + 1,
                if idx % 2 == 0 { "speed" } else { "curvature" }
            ),
        ),
    }
}

/// Fail a parsed outcome whose values are outside `limits`.
fn gate(outcome: Outcome, limits: &Limits, values: &[f64]) -> Outcome {
    if outcome.status == Status::Failed {
        return outcome;
    }
    let outcome = finite(outcome, values);
    if outcome.status == Status::Failed {
        return outcome;
    }
    match limits.check(values) {
        None => outcome,
        Some(reason) => Outcome::failed(Failure::Implausible, reason),
    }
}

fn closes(open: u8, close: u8) -> bool {
    matches!((open, close), (b'(', b')') | (b'[', b']'))
}

fn describe(tokens: &[Token], i: usize, text: &str) -> String {
    match tokens.get(i) {
        None => "the end of the answer".to_owned(),
        Some(t) => {
            let snippet: String = text[t.pos..].chars().take(12).collect();
            format!("{snippet:?} at position {}", t.pos)
        }
    }
}

/// The strict grammar: `[` pair (`,` pair){n-1} `]` and nothing else.
fn strict(tokens: &[Token], text: &str, n: usize, out: &mut [f64]) -> Result<(), String> {
    if tokens.is_empty() {
        return Err("empty answer".to_owned());
    }
    let mut i = 0;
    if tokens[0].kind != Kind::Open(b'[') {
        return Err(format!(
            "not a bare list: expected '[' but found {}",
            describe(tokens, 0, text)
        ));
    }
    i += 1;
    for k in 0..n {
        if k > 0 {
            if tokens.get(i).map(|t| t.kind) != Some(Kind::Comma) {
                return Err(format!(
                    "expected ',' before pair {} but found {}",
                    k + 1,
                    describe(tokens, i, text)
                ));
            }
            i += 1;
        }
        let pair = match tokens.get(i..i + 5) {
            Some(
                &[Token {
                    kind: Kind::Open(o),
                    ..
                }, Token {
                    kind:
                        Kind::Num {
                            value: v,
                            plain: pv,
                        },
                    ..
                }, Token {
                    kind: Kind::Comma, ..
                }, Token {
                    kind:
                        Kind::Num {
                            value: c,
                            plain: pc,
                        },
                    ..
                }, Token {
                    kind: Kind::Close(cl),
                    ..
                }],
            ) if closes(o, cl) => (v, pv, c, pc),
            _ => {
                return Err(format!(
                    "pair {} is not '(v, c)': found {}",
                    k + 1,
                    describe(tokens, i, text)
                ))
            }
        };
        let (v, pv, c, pc) = pair;
        if !(v.is_finite() && c.is_finite()) {
            return Err(format!("pair {} has a non-finite number", k + 1));
        }
        if !(pv && pc) {
            return Err(format!("pair {} uses a non-ASCII minus sign", k + 1));
        }
        out[2 * k] = v;
        out[2 * k + 1] = c;
        i += 5;
    }
    match tokens.get(i).map(|t| t.kind) {
        Some(Kind::Close(b']')) => {}
        Some(Kind::Comma) if matches!(tokens.get(i + 1).map(|t| t.kind), Some(Kind::Open(_))) => {
            return Err(format!("more than {n} pairs"));
        }
        _ => {
            return Err(format!(
                "expected ']' after pair {n} but found {}",
                describe(tokens, i, text)
            ))
        }
    }
    if i + 1 < tokens.len() {
        return Err(format!(
            "text after the list: {}",
            describe(tokens, i + 1, text)
        ));
    }
    Ok(())
}

/// The lenient search: the first `n` bracketed pairs, else the first `2n` numbers.
fn lenient(tokens: &[Token], n: usize, out: &mut [f64]) -> Result<(), String> {
    let mut pairs = 0;
    let mut i = 0;
    while i < tokens.len() && pairs < n {
        if let Some((v, c, len)) = pair_at(tokens, i) {
            out[2 * pairs] = v;
            out[2 * pairs + 1] = c;
            pairs += 1;
            i += len;
        } else {
            i += 1;
        }
    }
    if pairs == n {
        return Ok(());
    }
    let mut count = 0;
    for t in tokens {
        if let Kind::Num { value, .. } = t.kind {
            out[count] = value;
            count += 1;
            if count == 2 * n {
                return Ok(());
            }
        }
    }
    Err(format!(
        "found {pairs} (v, c) pair(s) and {count} number(s); need {n} pairs or {} numbers",
        2 * n
    ))
}

/// A pair `(a, b)`, `[a; b]` or `(a b)` starting at token `i`: (a, b, tokens used).
fn pair_at(tokens: &[Token], i: usize) -> Option<(f64, f64, usize)> {
    if !matches!(tokens.get(i)?.kind, Kind::Open(_)) {
        return None;
    }
    let a = match tokens.get(i + 1)?.kind {
        Kind::Num { value, .. } => value,
        _ => return None,
    };
    let mut j = i + 2;
    if matches!(tokens.get(j)?.kind, Kind::Comma | Kind::Semicolon) {
        j += 1;
    }
    let b = match tokens.get(j)?.kind {
        Kind::Num { value, .. } => value,
        _ => return None,
    };
    match tokens.get(j + 1)?.kind {
        // mismatched closers (`(5, 0.1]`) are accepted: the pair is unambiguous
        Kind::Close(_) => Some((a, b, j + 2 - i)),
        _ => None,
    }
}

/// A parsed batch: values (`N × n × 2`, NaN where failed), status and failure codes, reasons.
pub type Batch = (Vec<f64>, Vec<u8>, Vec<u8>, Vec<String>);

/// Parse a batch of answers.
pub fn parse_batch<S: AsRef<str>>(
    texts: &[S],
    n: usize,
    mode: Mode,
    limits: &Limits,
) -> CoreResult<Batch> {
    if n == 0 {
        return Err(CoreError::Argument("n must be at least 1".to_owned()));
    }
    let mut values = vec![f64::NAN; texts.len() * 2 * n];
    let mut status = Vec::with_capacity(texts.len());
    let mut failure = Vec::with_capacity(texts.len());
    let mut reasons = Vec::with_capacity(texts.len());
    let mut parser = Parser::new();
    for (text, out) in texts.iter().zip(values.chunks_exact_mut(2 * n)) {
        let o = parser.parse_into(text.as_ref(), n, mode, limits, out);
        status.push(o.status as u8);
        failure.push(o.failure as u8);
        reasons.push(o.reason);
    }
    Ok((values, status, failure, reasons))
}

#[cfg(test)]
mod tests {
    use super::*;

    const SIX: [f64; 12] = [
        5.0, 0.01, 5.5, 0.0, 6.0, -0.02, 6.5, 0.0, 7.0, 0.0, 7.5, 0.003,
    ];

    fn run(text: &str, mode: Mode) -> Parsed {
        Parser::new().parse(text, 6, mode, &Limits::DEFAULT)
    }

    #[test]
    fn strict_accepts_the_exact_format() {
        let p = run(
            "[(5.0, 0.01), (5.5, 0.0), (6.0, -0.02), (6.5, 0.0), (7.0, 0.0), (7.5, 0.003)]",
            Mode::Lenient,
        );
        assert_eq!(p.status, Status::Ok);
        assert_eq!(p.values.unwrap(), SIX.to_vec());
        assert_eq!(p.reason, "");
    }

    #[test]
    fn strict_accepts_square_pairs_and_whitespace() {
        let p = run(
            "  \n[[5.0,0.01],[5.5,0.0],[6.0,-0.02],[6.5,0],[7,0.0],[7.5,3e-3]]\n",
            Mode::Strict,
        );
        assert_eq!(p.status, Status::Ok);
        assert_eq!(p.values.unwrap(), SIX.to_vec());
    }

    #[test]
    fn prose_around_the_list_is_corrected() {
        let p = run(
            "Sure! Here are the actions: [(5.0, 0.01), (5.5, 0.0), (6.0, -0.02), (6.5, 0.0), (7.0, 0.0), (7.5, 0.003)]. Drive safely.",
            Mode::Lenient,
        );
        assert_eq!(p.status, Status::Corrected);
        assert!(p.reason.contains("expected '['"), "{}", p.reason);
        assert_eq!(p.values.unwrap(), SIX.to_vec());
    }

    #[test]
    fn strict_mode_fails_what_lenient_corrects() {
        let p = run(
            "```\n[(5,0),(5,0),(5,0),(5,0),(5,0),(5,0)]\n```",
            Mode::Strict,
        );
        assert_eq!(p.status, Status::Failed);
        assert!(p.values.is_none());
    }

    #[test]
    fn labels_fall_back_to_numbers() {
        let text = "v1 = 5.0, c1 = 0.01\nv2 = 5.5, c2 = 0.0\nv3 = 6.0, c3 = -0.02\nv4 = 6.5, c4 = 0\nv5 = 7, c5 = 0\nv6 = 7.5, c6 = 0.003";
        let p = run(text, Mode::Lenient);
        assert_eq!(p.status, Status::Corrected);
        assert_eq!(p.values.unwrap(), SIX.to_vec());
    }

    #[test]
    fn too_few_numbers_fail_with_counts() {
        let p = run("[(5.0, 0.01), (5.5, 0.0)]", Mode::Lenient);
        assert_eq!(p.status, Status::Failed);
        assert!(
            p.reason.contains("found 2 (v, c) pair(s) and 4 number(s)"),
            "{}",
            p.reason
        );
    }

    #[test]
    fn non_finite_never_passes() {
        let p = run(
            "[(5.0, nan), (5.5, 0.0), (6.0, -0.02), (6.5, 0.0), (7.0, 0.0), (7.5, 0.003)]",
            Mode::Lenient,
        );
        assert_eq!(p.status, Status::Failed);
        assert!(p.reason.contains("non-finite curvature"), "{}", p.reason);
        let p = run(
            "[(1e999, 0), (5.5, 0.0), (6.0, -0.02), (6.5, 0.0), (7.0, 0.0), (7.5, 0.003)]",
            Mode::Lenient,
        );
        assert_eq!(p.status, Status::Failed);
    }

    #[test]
    fn too_many_pairs_strict_fails_lenient_takes_first() {
        let text = "[(1,0),(2,0),(3,0),(4,0),(5,0),(6,0),(7,0)]";
        let p = run(text, Mode::Lenient);
        assert_eq!(p.status, Status::Corrected);
        assert!(p.reason.contains("more than 6 pairs"), "{}", p.reason);
        assert_eq!(p.values.unwrap()[10], 6.0);
    }

    #[test]
    fn unicode_minus_is_corrected() {
        let p = run(
            "[(5.0, \u{2212}0.01), (5, 0), (5, 0), (5, 0), (5, 0), (5, 0)]",
            Mode::Lenient,
        );
        assert_eq!(p.status, Status::Corrected);
        assert_eq!(p.values.unwrap()[1], -0.01);
    }

    #[test]
    fn hostile_inputs_terminate() {
        let digits = "9".repeat(1 << 20);
        assert_eq!(run(&digits, Mode::Lenient).status, Status::Failed);
        let nested = "[".repeat(100_000) + &"]".repeat(100_000);
        assert_eq!(run(&nested, Mode::Lenient).status, Status::Failed);
        assert_eq!(run("", Mode::Lenient).reason, "empty answer");
    }

    #[test]
    fn batch_layout_and_unknown_mode() {
        let (values, status, failure, reasons) = parse_batch(
            &["[(1,2),(3,4),(5,6),(7,8),(9,10),(11,12)]", "nope"],
            6,
            Mode::Lenient,
            &Limits::NONE,
        )
        .unwrap();
        assert_eq!(failure, vec![0, 3]);
        assert_eq!(values.len(), 24);
        assert_eq!(values[11], 12.0);
        assert!(values[12].is_nan());
        assert_eq!(status, vec![0, 2]);
        assert!(reasons[0].is_empty() && !reasons[1].is_empty());
        assert!(Mode::from_name("fuzzy").is_err());
        assert!(parse_batch(&["x"], 0, Mode::Lenient, &Limits::NONE).is_err());
    }
}
