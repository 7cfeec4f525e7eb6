//! Parsing a model's stage-3 answer into `n` (speed, curvature) actions.
//!
//! * **strict**: after trimming, the whole answer is `[(v, c), …]` with exactly
//!   `n` pairs of finite plain numbers (round or square inner brackets).
//! * **lenient**: the strict format, else the actions found in the answer's
//!   structure (see [`lenient`]).
//! * **paper**: the paper's own FE / FE corr rules (see [`paper`]).
//! * **json**: a provider's structured output `{"actions": [[v, c], …]}` (see [`json`]).
//!
//! Strict, lenient and json answers then pass a plausibility gate ([`Limits`]).
//! Every answer gets a [`Status`], a [`Failure`] kind and, unless plainly `Ok`, a short reason.
//!
//! The parsers' parts are this module's children: [`lexer`] (the tokens of an answer), [`lenient`] (the actions
//! found in an answer's structure), [`paper`] (the paper's rules) and [`json`] (structured output).

pub mod json;
pub mod lenient;
pub mod lexer;
pub mod paper;

use crate::error::{CoreError, CoreResult};
use lenient::{answer_ranges, Blocks, Lenient, Reading};
use lexer::{tokenize, tokenize_range, Kind, Token};

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
    /// The statuses by code (`Status as u8` indexes it): `_core.PARSE_STATUSES`.
    pub const NAMES: &'static [&'static str] = &["ok", "corrected", "failed"];

    pub fn as_str(self) -> &'static str {
        Self::NAMES[self as usize]
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
    /// Readings disagree: several different lists and no cue saying which is final, a
    /// range or subtraction inside a pair (`4.5-5.0`), standalone numbers whose pairing
    /// the layout does not give.
    Ambiguous = 4,
}

impl Failure {
    pub const NAMES: &'static [&'static str] =
        &["", "truncated", "implausible", "format", "ambiguous"];

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
                        "speed {} at step {} outside [{}, {}] m/s",
                        short(v),
                        step + 1,
                        short(lo),
                        short(hi)
                    ));
                }
            }
            if let Some(k) = self.curvature {
                if c.abs() > k {
                    return Some(format!(
                        "curvature {} at step {} outside [-{}, {}] 1/m",
                        short(c),
                        step + 1,
                        short(k),
                        short(k)
                    ));
                }
            }
        }
        None
    }
}

/// A value for a reason: as written for everyday magnitudes (`5254`, `-0.02`), in short
/// scientific notation beyond them (`1e308`, `2.5e-9`), never a 309-digit number.
pub fn short(x: f64) -> String {
    let a = x.abs();
    if a != 0.0 && !(1e-6..1e9).contains(&a) {
        format!("{x:e}")
    } else {
        format!("{x}")
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
    ranges: Vec<(usize, usize)>,
    lenient: Lenient,
}

impl Parser {
    pub fn new() -> Self {
        Self::default()
    }

    /// Parse one answer for `n` actions. The values are written into `out` (length `2n`,
    /// NaN where failed). `history` (`2n` values v1, c1, …: the history the prompt
    /// printed) makes a lenient candidate equal to it a quotation, never the answer.
    pub fn parse_into(
        &mut self,
        text: &str,
        n: usize,
        mode: Mode,
        limits: &Limits,
        history: Option<&[f64]>,
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
            Mode::Strict | Mode::Lenient => self.strict_or_lenient(text, n, mode, history, out),
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

    fn strict_or_lenient(
        &mut self,
        text: &str,
        n: usize,
        mode: Mode,
        history: Option<&[f64]>,
        out: &mut [f64],
    ) -> Outcome {
        let maybe_tags = tokenize(text, &mut self.tokens, &mut self.scratch);
        if self.tokens.is_empty() {
            return Outcome::failed(Failure::Format, "empty answer".to_owned());
        }
        let strict_err = match strict(&self.tokens, n, out) {
            Ok(()) => return Outcome::ok(),
            Err(e) => e,
        };
        if mode == Mode::Strict {
            let reason = strict_err.message(&self.tokens, text, n);
            return if strict_err.truncated {
                Outcome::failed(Failure::Truncated, format!("truncated: {reason}"))
            } else {
                Outcome::failed(Failure::Format, reason)
            };
        }
        let blocks = if maybe_tags {
            answer_ranges(text, &mut self.ranges)
        } else {
            Blocks::default()
        };
        if blocks.unclosed {
            return Outcome::failed(
                Failure::Truncated,
                "truncated: the answer ends inside a reasoning block".to_owned(),
            );
        }
        if blocks.removed > 0 {
            self.tokens.clear();
            for &(start, end) in &self.ranges {
                tokenize_range(text, start, end, &mut self.tokens, &mut self.scratch);
            }
        }
        match self.lenient.read(&self.tokens, text, n, history, out) {
            Reading::Found(mut notes) => {
                if blocks.removed > 0 {
                    notes.insert(0, "reasoning block removed".to_owned());
                }
                let reason = if notes.is_empty() {
                    // the list is the whole answer: the strict error says what differs
                    strict_err.message(&self.tokens, text, n)
                } else {
                    notes.join("; ")
                };
                Outcome::corrected(reason)
            }
            Reading::Truncated(reason) => Outcome::failed(Failure::Truncated, reason),
            Reading::Failed(reason) => Outcome::failed(Failure::Format, reason),
            Reading::Ambiguous(reason) => Outcome::failed(Failure::Ambiguous, reason),
        }
    }

    /// Convenience wrapper returning a [`Parsed`].
    pub fn parse(&mut self, text: &str, n: usize, mode: Mode, limits: &Limits) -> Parsed {
        self.parse_with_history(text, n, mode, limits, None)
    }

    /// [`Parser::parse`] with the frame's history (`2n` values).
    pub fn parse_with_history(
        &mut self,
        text: &str,
        n: usize,
        mode: Mode,
        limits: &Limits,
        history: Option<&[f64]>,
    ) -> Parsed {
        let mut values = vec![f64::NAN; 2 * n];
        let o = self.parse_into(text, n, mode, limits, history, &mut values);
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

/// Why the strict grammar failed, at which token; formatted only when a reason is needed.
#[derive(Debug, Clone, Copy)]
enum StrictWhat {
    NotList,
    NoComma(usize),
    NotPair(usize),
    NonFinite(usize),
    Unicode(usize),
    MorePairs,
    NoClose,
    TextAfter,
}

#[derive(Debug, Clone, Copy)]
struct StrictError {
    what: StrictWhat,
    at: usize,
    /// the answer ended before the list did
    truncated: bool,
}

impl StrictError {
    fn message(&self, tokens: &[Token], text: &str, n: usize) -> String {
        let found = || describe(tokens, self.at, text);
        match self.what {
            StrictWhat::NotList => format!("not a bare list: expected '[' but found {}", found()),
            StrictWhat::NoComma(k) => {
                format!("expected ',' before pair {} but found {}", k + 1, found())
            }
            StrictWhat::NotPair(k) => format!("pair {} is not '(v, c)': found {}", k + 1, found()),
            StrictWhat::NonFinite(k) => format!("pair {} has a non-finite number", k + 1),
            StrictWhat::Unicode(k) => format!("pair {} uses a non-ASCII minus sign", k + 1),
            StrictWhat::MorePairs => format!("more than {n} pairs"),
            StrictWhat::NoClose => format!("expected ']' after pair {n} but found {}", found()),
            StrictWhat::TextAfter => format!("text after the list: {}", found()),
        }
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
fn strict(tokens: &[Token], n: usize, out: &mut [f64]) -> Result<(), StrictError> {
    let fail = |what: StrictWhat, at: usize| StrictError {
        what,
        at,
        truncated: at >= tokens.len(),
    };
    if tokens.first().map(|t| t.kind) != Some(Kind::Open(b'[')) {
        return Err(fail(StrictWhat::NotList, 0));
    }
    let mut i = 1;
    for k in 0..n {
        if k > 0 {
            if tokens.get(i).map(|t| t.kind) != Some(Kind::Comma) {
                return Err(fail(StrictWhat::NoComma(k), i));
            }
            i += 1;
        }
        let pair = match tokens.get(i..i + 5) {
            Some([a, b, c, d, e]) => match (a.kind, b.kind, c.kind, d.kind, e.kind) {
                (
                    Kind::Open(o),
                    Kind::Num {
                        value: v,
                        plain: pv,
                        ..
                    },
                    Kind::Comma,
                    Kind::Num {
                        value: c,
                        plain: pc,
                        ..
                    },
                    Kind::Close(cl),
                ) if closes(o, cl) => Some((v, pv, c, pc)),
                _ => None,
            },
            _ => None,
        };
        let Some((v, pv, c, pc)) = pair else {
            // the answer may end inside this pair
            let at = if tokens.len() < i + 5 {
                tokens.len()
            } else {
                i
            };
            let mut e = fail(StrictWhat::NotPair(k), i);
            e.truncated = at >= tokens.len();
            return Err(e);
        };
        if !(v.is_finite() && c.is_finite()) {
            return Err(fail(StrictWhat::NonFinite(k), i));
        }
        if !(pv && pc) {
            return Err(fail(StrictWhat::Unicode(k), i));
        }
        out[2 * k] = v;
        out[2 * k + 1] = c;
        i += 5;
    }
    match tokens.get(i).map(|t| t.kind) {
        Some(Kind::Close(b']')) => {}
        Some(Kind::Comma) if matches!(tokens.get(i + 1).map(|t| t.kind), Some(Kind::Open(_))) => {
            return Err(fail(StrictWhat::MorePairs, i));
        }
        _ => return Err(fail(StrictWhat::NoClose, i)),
    }
    if i + 1 < tokens.len() {
        return Err(fail(StrictWhat::TextAfter, i + 1));
    }
    Ok(())
}

/// A parsed batch: values (`N × n × 2`, NaN where failed), status and failure codes, reasons.
pub type Batch = (Vec<f64>, Vec<u8>, Vec<u8>, Vec<String>);

/// Parse a batch of answers. `history`, when given, holds each answer's history
/// (`N × n × 2` values, v1, c1, … per answer; see [`Parser::parse_into`]).
pub fn parse_batch<S: AsRef<str>>(
    texts: &[S],
    n: usize,
    mode: Mode,
    limits: &Limits,
    history: Option<&[f64]>,
) -> CoreResult<Batch> {
    if n == 0 {
        return Err(CoreError::Argument("n must be at least 1".to_owned()));
    }
    if let Some(h) = history {
        if h.len() != texts.len() * 2 * n {
            return Err(CoreError::Shape(format!(
                "history must have shape ({}, {n}, 2) like the texts, got {} values",
                texts.len(),
                h.len()
            )));
        }
    }
    let mut values = vec![f64::NAN; texts.len() * 2 * n];
    let mut status = Vec::with_capacity(texts.len());
    let mut failure = Vec::with_capacity(texts.len());
    let mut reasons = Vec::with_capacity(texts.len());
    let mut parser = Parser::new();
    for (i, (text, out)) in texts.iter().zip(values.chunks_exact_mut(2 * n)).enumerate() {
        let h = history.map(|h| &h[i * 2 * n..(i + 1) * 2 * n]);
        let o = parser.parse_into(text.as_ref(), n, mode, limits, h, out);
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
    const EXACT: &str =
        "[(5.0, 0.01), (5.5, 0.0), (6.0, -0.02), (6.5, 0.0), (7.0, 0.0), (7.5, 0.003)]";

    fn run(text: &str, mode: Mode) -> Parsed {
        Parser::new().parse(text, 6, mode, &Limits::DEFAULT)
    }

    fn lenient(text: &str) -> Parsed {
        run(text, Mode::Lenient)
    }

    fn list(pairs: &[(&str, &str)]) -> String {
        let inner: Vec<String> = pairs.iter().map(|(v, c)| format!("({v}, {c})")).collect();
        format!("[{}]", inner.join(", "))
    }

    #[test]
    fn strict_accepts_the_exact_format() {
        let p = lenient(EXACT);
        assert_eq!((p.status, p.failure), (Status::Ok, Failure::None));
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
        let p = lenient(&format!(
            "Sure! Here are the actions: {EXACT}. Drive safely."
        ));
        assert_eq!(p.status, Status::Corrected);
        assert_eq!(p.reason, "text around the list");
        assert_eq!(p.values.unwrap(), SIX.to_vec());
    }

    #[test]
    fn strict_mode_fails_what_lenient_corrects() {
        let p = run(&format!("```\n{EXACT}\n```"), Mode::Strict);
        assert_eq!((p.status, p.failure), (Status::Failed, Failure::Format));
        assert!(p.values.is_none());
    }

    #[test]
    fn strict_mode_reports_truncation() {
        let p = run(&EXACT[..EXACT.len() - 9], Mode::Strict);
        assert_eq!(p.failure, Failure::Truncated, "{}", p.reason);
        assert!(p.reason.starts_with("truncated"));
    }

    #[test]
    fn labels_fall_back_to_numbers() {
        let text = "v1 = 5.0, c1 = 0.01\nv2 = 5.5, c2 = 0.0\nv3 = 6.0, c3 = -0.02\nv4 = 6.5, c4 = 0\nv5 = 7, c5 = 0\nv6 = 7.5, c6 = 0.003";
        let p = lenient(text);
        assert_eq!(p.status, Status::Corrected);
        assert_eq!(p.values.unwrap(), SIX.to_vec());
        assert!(p.reason.contains("12 standalone numbers"), "{}", p.reason);
    }

    fn with_history(text: &str, history: &[f64]) -> Parsed {
        Parser::new().parse_with_history(text, 6, Mode::Lenient, &Limits::DEFAULT, Some(history))
    }

    const HISTORY: [f64; 12] = [4.5, 0.0, 4.6, 0.0, 4.7, 0.0, 4.8, 0.0, 4.9, 0.0, 5.0, 0.0];
    const HISTORY_TEXT: &str =
        "[(4.5, 0.0), (4.6, 0.0), (4.7, 0.0), (4.8, 0.0), (4.9, 0.0), (5.0, 0.0)]";

    fn assert_ambiguous(p: &Parsed, needle: &str) {
        assert_eq!(
            (p.status, p.failure),
            (Status::Failed, Failure::Ambiguous),
            "{}",
            p.reason
        );
        assert!(p.values.is_none());
        assert!(p.reason.contains(needle), "{}", p.reason);
    }

    #[test]
    fn kind_1_quoted_history_before_the_answer() {
        let text = format!("Past actions: {HISTORY_TEXT}. So: {EXACT}");
        // without the history, two different lists: which is the answer is unknown
        assert_ambiguous(&lenient(&text), "2 different lists of 6 actions");
        // with it, the quotation is no candidate
        let p = with_history(&text, &HISTORY);
        assert_eq!(p.status, Status::Corrected);
        assert_eq!(p.values.unwrap(), SIX.to_vec());
        assert!(
            p.reason.contains(
                "skipped 1 list(s) repeating the history given in the prompt (at position 14)"
            ),
            "{}",
            p.reason
        );
        let p = lenient(&format!(
            "<think>The history {HISTORY_TEXT} covers 3 seconds at 0.5 s.</think>\n{EXACT}"
        ));
        assert_eq!(p.values.unwrap(), SIX.to_vec());
        assert!(p.reason.contains("reasoning block removed"), "{}", p.reason);
    }

    #[test]
    fn a_recap_after_the_answer_is_ambiguous_unless_it_is_the_history() {
        let answer =
            "[(5.0, 0.0), (5.2, 0.01), (5.4, 0.01), (5.6, 0.02), (5.8, 0.02), (6.0, 0.03)]";
        let text = format!("{answer}\nFor comparison, the past actions were {HISTORY_TEXT}.");
        let p = lenient(&text);
        assert_ambiguous(&p, "2 different lists of 6 actions");
        assert!(p.reason.contains("at positions 0 and"), "{}", p.reason);
        let p = with_history(&text, &HISTORY);
        assert_eq!(p.status, Status::Corrected, "{}", p.reason);
        assert_eq!(p.values.unwrap()[..4], [5.0, 0.0, 5.2, 0.01]);
        // the history is compared at the precision the prompt printed: 4.50 is 4.5, 4.51 is not
        let p = with_history(&text.replace("(4.5, 0.0)", "(4.50, 0.000)"), &HISTORY);
        assert_eq!(p.status, Status::Corrected, "{}", p.reason);
        let p = with_history(&text.replace("(4.5, 0.0)", "(4.51, 0.0)"), &HISTORY);
        assert_eq!(p.failure, Failure::Ambiguous, "{}", p.reason);
        // waypoints, accelerations, an alternative plan after the answer: ambiguous
        for tail in [
            "Waypoints: [(2.5, 0.0), (5.1, 0.0), (7.8, 0.1), (10.6, 0.2), (13.5, 0.4), (16.5, 0.6)]",
            "Accelerations: [(0.4, 0.0), (0.4, 0.0), (0.4, 0.0), (0.4, 0.0), (0.4, 0.0), (0.4, 0.0)]",
            "Alternatively, [(3.0, 0.0), (2.0, 0.0), (1.0, 0.0), (0.0, 0.0), (0.0, 0.0), (0.0, 0.0)]",
        ] {
            assert_ambiguous(&with_history(&format!("{answer}\n{tail}"), &HISTORY), "different lists");
        }
        // a history that is the only list contradicts nothing: it is the answer (stay stopped)
        let p = with_history(&format!("Keep it: {HISTORY_TEXT}."), &HISTORY);
        assert_eq!(p.values.as_deref(), Some(&HISTORY[..]), "{}", p.reason);
        assert!(
            p.reason
                .contains("the list equals the history given in the prompt (no other list)"),
            "{}",
            p.reason
        );
        let p = with_history(
            &format!("Keep it: {HISTORY_TEXT}. Same: {HISTORY_TEXT}"),
            &HISTORY,
        );
        assert_eq!(p.values.as_deref(), Some(&HISTORY[..]), "{}", p.reason);
        // the same list twice is one candidate
        let p = lenient(&format!("{EXACT}\nTo repeat: {EXACT}"));
        assert_eq!(p.values.unwrap(), SIX.to_vec());
        assert!(
            p.reason.contains("the same list given 2 times"),
            "{}",
            p.reason
        );
    }

    #[test]
    fn an_answer_equal_to_the_history_is_an_answer_unless_the_text_calls_it_the_past() {
        // issue 32: a draft, then a final answer that keeps the history's pace
        let draft = list(&[
            ("4.0", "0.0"),
            ("3.0", "0.0"),
            ("2.0", "0.0"),
            ("1.0", "0.0"),
            ("0.0", "0.0"),
            ("0.0", "0.0"),
        ]);
        let text = format!("Draft: {draft}\nFinal answer: {HISTORY_TEXT}");
        let p = with_history(&text, &HISTORY);
        assert_eq!(p.values.as_deref(), Some(&HISTORY[..]), "{}", p.reason);
        assert!(
            p.reason.contains("took the list after the cue \"Final\"")
                && p.reason
                    .contains("the list equals the history given in the prompt"),
            "{}",
            p.reason
        );
        // the history, then a degenerate list, no cue: two readings
        let degenerate = list(&[("0.005", "0.005"); 6]);
        for text in [
            format!("{HISTORY_TEXT}\n{degenerate}"),
            format!("Keep the pace: {HISTORY_TEXT}\n{degenerate}"),
            // a past word in an earlier sentence says nothing of this list
            format!("The history is steady. Keep it: {HISTORY_TEXT}\n{degenerate}"),
            format!("{degenerate}\nKeep the pace: {HISTORY_TEXT}"),
        ] {
            assert_ambiguous(&with_history(&text, &HISTORY), "2 different lists");
        }
        // the text calls it the past: a quotation
        for text in [
            format!("Previous actions: {HISTORY_TEXT}\nPlan: {degenerate}"),
            format!("{degenerate} (the past: {HISTORY_TEXT})"),
            format!("Given the HISTORY {HISTORY_TEXT}, slow down: {degenerate}"),
        ] {
            let p = with_history(&text, &HISTORY);
            assert_eq!(
                p.values.unwrap()[..2],
                [0.005, 0.005],
                "{text}: {}",
                p.reason
            );
            assert!(
                p.reason.contains("skipped 1 list(s) repeating the history"),
                "{}",
                p.reason
            );
        }
        // a final-answer cue after the quotation points at another list
        let p = with_history(
            &format!("{HISTORY_TEXT}\nFinal answer: {degenerate}"),
            &HISTORY,
        );
        assert_eq!(p.values.unwrap()[..2], [0.005, 0.005], "{}", p.reason);
        // a cue and a past word introducing the history beside a different list: ambiguous
        for text in [
            format!("{degenerate}\nFinal answer: keep the previous actions {HISTORY_TEXT}"),
            format!("{degenerate}\nWait, the past actions were {HISTORY_TEXT}"),
        ] {
            assert_ambiguous(
                &with_history(&text, &HISTORY),
                "introduced both as the past",
            );
        }
        // alone it is the answer, whatever introduces it
        let p = with_history(
            &format!("Final answer: keep the previous actions {HISTORY_TEXT}"),
            &HISTORY,
        );
        assert_eq!(p.values.as_deref(), Some(&HISTORY[..]), "{}", p.reason);
    }

    #[test]
    fn a_cue_between_lists_says_which_is_final() {
        let first = list(&[("8.0", "0.0"); 6]);
        for cue in [
            "Correction:",
            "Final answer:",
            "**Final Answer**",
            "Revised plan:",
            "Actually, slower:",
            "Wait, the light is red.",
            "Corrected:",
        ] {
            let p = lenient(&format!("{first}\n{cue} {EXACT}"));
            assert_eq!(p.values.as_deref(), Some(&SIX[..]), "{cue}: {}", p.reason);
            assert!(
                p.reason.contains("took the list after the cue"),
                "{}",
                p.reason
            );
        }
        // a cue before every list decides nothing; nor does one not followed by a list
        assert_ambiguous(
            &lenient(&format!("Final answer: {first}\n{EXACT}")),
            "different lists",
        );
        assert_ambiguous(
            &lenient(&format!("{first}\n{EXACT} Wait, maybe.")),
            "different lists",
        );
        // after the cue the lists must agree
        let p = lenient(&format!(
            "{first}\nWait: {EXACT}\nFor comparison: {}",
            list(&[("1.0", "0.0"); 6])
        ));
        assert_ambiguous(&p, "after the cue \"Wait\"");
        // prose that is no cue
        for words in [
            "Also",
            "Alternatively,",
            "For comparison",
            "The final speed is fine.",
            "Or we could wait for the pedestrian",
            "if the light is actually red",
            "the corrected history",
        ] {
            assert_ambiguous(
                &lenient(&format!("{first}\n{words} {EXACT}")),
                "different lists",
            );
        }
    }

    #[test]
    fn kind_2_self_correction_takes_the_last_list() {
        let first = list(&[("8.0", "0.0"); 6]);
        let p = lenient(&format!(
            "{first}\nWait, that ignores the red light. Corrected: {EXACT}"
        ));
        assert_eq!(p.values.unwrap(), SIX.to_vec());
    }

    #[test]
    fn kind_3_prose_numbers_are_not_actions() {
        let text = "Over the next 3 seconds at 0.5 s steps:\nv1 = 5.0, c1 = 0.01\nv2 = 5.5, c2 = 0.0\nv3 = 6.0, c3 = -0.02\nv4 = 6.5, c4 = 0\nv5 = 7, c5 = 0\nv6 = 7.5, c6 = 0.003";
        let p = lenient(text);
        assert_eq!(p.values.unwrap(), SIX.to_vec(), "{}", p.reason);
        // one number too many: fail rather than guess which
        let p = lenient(&format!("Keep about 6.2 m/s.\n{text}"));
        assert_eq!((p.status, p.failure), (Status::Failed, Failure::Format));
        assert!(p.reason.contains("13 standalone"), "{}", p.reason);
    }

    #[test]
    fn kind_4_arithmetic_is_evaluated() {
        let p = lenient(&list(&[("7.2+0.5", "0.002"); 6]));
        assert_eq!(p.status, Status::Corrected);
        let v = p.values.unwrap();
        assert!((v[0] - 7.7).abs() < 1e-12 && v[1] == 0.002);
        assert!(
            p.reason
                .contains("expression evaluated (pair 1, 2, 3, 4, 5, 6)"),
            "{}",
            p.reason
        );
        let p = lenient(&list(&[("5.0", "1/50"); 6]));
        assert_eq!(p.values.unwrap()[..2], [5.0, 0.02]);
        let p = lenient(&list(&[("5.0", "0.5*0.02"); 6]));
        assert_eq!(p.values.unwrap()[..2], [5.0, 0.01]);
    }

    #[test]
    fn a_range_is_not_a_subtraction() {
        for (v, c, item) in [
            ("4.5-5.0", "0.0", "4.5-5.0"),
            ("4.5 - 5.0", "0.0", "4.5 - 5.0"),
            ("4.5 -5.0", "0.0", "4.5 -5.0"),
            ("4.5\u{2013}5.0", "0.0", "4.5\u{2013}5.0"),
            ("5.0", "0.01-0.02", "0.01-0.02"),
        ] {
            let p = lenient(&list(&[(v, c); 6]));
            assert_ambiguous(
                &p,
                &format!("is ambiguous: {item} is a range or a subtraction"),
            );
            assert!(p.reason.starts_with("pair 1 ("), "{}", p.reason);
        }
        // space-separated, a signed second number is a value
        let p = lenient(
            "[(5.0 -0.01), (5.0 -0.01), (5.0 -0.01), (5.0 -0.01), (5.0 -0.01), (5.0 -0.01)]",
        );
        assert_eq!(p.values.unwrap()[..2], [5.0, -0.01]);
        // standalone numbers with a range
        let p = lenient("Speeds: 4.5-5.0, 5, 5, 5, 5, 5\nCurvatures: 0, 0, 0, 0, 0, 0");
        assert_ambiguous(&p, "\"4.5-5.0\" at position 8 is a range or a subtraction");
    }

    #[test]
    fn a_doubled_sign_fails() {
        for item in ["--0.01", "+-0.01", "- -0.01", "-\u{2212}0.01"] {
            let p = lenient(&list(&[("5.0", item); 6]));
            assert_eq!(
                (p.status, p.failure),
                (Status::Failed, Failure::Format),
                "{item}"
            );
            assert!(
                p.reason.contains("has a doubled sign"),
                "{item}: {}",
                p.reason
            );
        }
        let p = lenient(&list(&[("5.0+-0.1", "0.0"); 6]));
        assert!(p.reason.contains("doubled sign"), "{}", p.reason);
        let p = lenient("5.0 --0.01 5.0 0.0 5.0 0.0 5.0 0.0 5.0 0.0 5.0 0.0");
        assert_eq!(p.failure, Failure::Format);
        assert!(p.reason.contains("has a doubled sign"), "{}", p.reason);
        // strict mode is unchanged: not a pair
        let p = run(&list(&[("5.0", "--0.01"); 6]), Mode::Strict);
        assert_eq!(p.failure, Failure::Format);
        assert!(
            p.reason.starts_with("pair 1 is not '(v, c)'"),
            "{}",
            p.reason
        );
    }

    #[test]
    fn labelled_sequences_are_read_by_their_labels() {
        let speeds = "0.8, 0.6, 0.4, 0.2, 0.0, 0.0";
        let curvatures = "0.01, 0.02, 0.03, 0.04, 0.05, 0.06";
        let want = [
            0.8, 0.01, 0.6, 0.02, 0.4, 0.03, 0.2, 0.04, 0.0, 0.05, 0.0, 0.06,
        ];
        for text in [
            format!("Speeds: {speeds}\nCurvatures: {curvatures}"),
            format!("Curvatures: {curvatures}\nSpeeds (m/s): {speeds}"),
            format!("v: [{speeds}] k: [{curvatures}]"),
            format!(r#"{{"speeds": [{speeds}], "curvatures": [{curvatures}]}}"#),
            format!(r#"{{"curvature": [{curvatures}], "speed": [{speeds}]}}"#),
            format!("Speeds: [{speeds}]\nCurvatures: [{curvatures}]"),
        ] {
            let p = lenient(&text);
            assert_eq!(p.status, Status::Corrected, "{text}: {}", p.reason);
            assert_eq!(p.values.unwrap(), want.to_vec(), "{text}");
        }
        let p = lenient(&format!("Speeds: {speeds}\nCurvatures: {curvatures}"));
        assert!(
            p.reason.contains("by their speed / curvature labels"),
            "{}",
            p.reason
        );
        // a table with speed and curvature columns, either order
        let rows: String = want
            .chunks(2)
            .map(|p| format!("| {} | {} |\n", p[0], p[1]))
            .collect();
        let p = lenient(&format!(
            "| Speed (m/s) | Curvature (1/m) |\n|---|---|\n{rows}"
        ));
        assert_eq!(p.values.unwrap(), want.to_vec(), "{rows}");
        let swapped: String = want
            .chunks(2)
            .map(|p| format!("| {} | {} |\n", p[1], p[0]))
            .collect();
        let p = lenient(&format!("| curvature | speed |\n|---|---|\n{swapped}"));
        assert_eq!(p.values.unwrap(), want.to_vec());
        // one pair per line, or per `;` group
        let lines: String = want
            .chunks(2)
            .map(|p| format!("{} {}\n", p[0], p[1]))
            .collect();
        assert_eq!(lenient(&lines).values.unwrap(), want.to_vec());
        let groups: Vec<String> = want
            .chunks(2)
            .map(|p| format!("{}, {}", p[0], p[1]))
            .collect();
        assert_eq!(lenient(&groups.join("; ")).values.unwrap(), want.to_vec());
    }

    #[test]
    fn loose_numbers_without_a_pairing_are_ambiguous() {
        for text in [
            "0.8, 0.6, 0.4, 0.2, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0",
            "I slow from 0.8 to 0.6 then 0.4 and 0.2 to 0.0 and 0.0 with curving 0.0 0.0 0.0 0.0 0.0 0.0",
            "Speeds: 0.8, 0.6, 0.4, 0.2, 0.0\nCurvatures: 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0",
        ] {
            let p = lenient(text);
            assert_ambiguous(&p, "12 standalone numbers, but their pairing is unknown");
        }
        // the issue's case: speeds then curvatures, at normal and at low speeds
        let p = lenient(
            "Speeds: 0.8, 0.6, 0.4, 0.2, 0.0, 0.0\nCurvatures: 0.0, 0.0, 0.0, 0.0, 0.0, 0.0",
        );
        assert_eq!(p.values.unwrap()[..4], [0.8, 0.0, 0.6, 0.0]);
        // two unlabelled lists of six numbers
        let p = lenient("[5.0, 5.2, 5.4, 5.6, 5.8, 6.0] and [0.0, 0.0, 0.01, 0.01, 0.0, 0.0]");
        assert_ambiguous(&p, "2 lists of 6 numbers, but which holds the speeds");
    }

    #[test]
    fn unambiguous_flat_and_spaced_lists_are_read() {
        let flat: Vec<String> = SIX.iter().map(f64::to_string).collect();
        let p = lenient(&format!("[{}]", flat.join(", ")));
        assert_eq!(p.status, Status::Corrected);
        assert_eq!(p.values.unwrap(), SIX.to_vec());
        assert!(
            p.reason.contains("a flat list of 12 numbers"),
            "{}",
            p.reason
        );
        let spaced: Vec<String> = SIX
            .chunks(2)
            .map(|p| format!("{} {}", p[0], p[1]))
            .collect();
        let p = lenient(&format!("Actions: [{}]", spaced.join(", ")));
        assert_eq!(p.values.unwrap(), SIX.to_vec(), "{}", p.reason);
        assert!(
            p.reason.contains("pairs written as 'v c' items"),
            "{}",
            p.reason
        );
        // real answers (GPT-4o, LLaMA-3.2-11B)
        let p = lenient("[11.478 0.0, 11.528 0.0, 11.578 0.0, 11.628 0.0, 11.678 0.0, 11.728 0.0]");
        assert_eq!(p.values.unwrap()[..4], [11.478, 0.0, 11.528, 0.0]);
        // a flat list of 13, or of 12 with one item of two numbers, is not read
        assert_eq!(
            lenient(&format!("[{}, 1.0]", flat.join(", "))).status,
            Status::Failed
        );
        assert_eq!(
            lenient(&format!("[{} 1.0]", flat.join(", "))).status,
            Status::Failed
        );
        // a flat list and a different pair list: ambiguous
        assert_ambiguous(
            &lenient(&format!(
                "[{}]\n{}",
                flat.join(", "),
                list(&[("1.0", "0.0"); 6])
            )),
            "different lists",
        );
        // the same actions both ways: one reading
        assert_eq!(
            lenient(&format!("[{}]\n{EXACT}", flat.join(", ")))
                .values
                .unwrap(),
            SIX.to_vec()
        );
    }

    #[test]
    fn kind_5_fused_numbers_fail_naming_the_pair() {
        let p = lenient("[(3.7640.002)(4.0140.001)(4.2640.001)(4.5140.0)(4.7640.0)(5.0140.0)]");
        assert_eq!((p.status, p.failure), (Status::Failed, Failure::Format));
        assert!(p.reason.starts_with("pair 1 (3.7640.002)"), "{}", p.reason);
        assert!(p.reason.contains("lost comma"), "{}", p.reason);
    }

    #[test]
    fn kind_6_lost_decimal_points_fail() {
        let p =
            lenient("[(5254,0001),(5559,00005),(5864,0001),(6170,0001),(6475,0001),(6780,0001)]");
        assert_eq!((p.status, p.failure), (Status::Failed, Failure::Format));
        assert!(p.reason.contains("0001 has leading zeros"), "{}", p.reason);
        let p = lenient(&list(&[("5254", "0.001"); 6]));
        assert_eq!(p.failure, Failure::Implausible);
        assert_eq!(p.reason, "speed 5254 at step 1 outside [-10, 50] m/s");
    }

    #[test]
    fn kind_7_cut_off_answers_are_truncated() {
        for text in [
            "[(5.0, 0.0), (5.1, 0.0), (5.2, 0.0), (5.3, 0.0), (5.5, 0.0), (5.6, -0.0",
            "[(5.0, 0.0), (5.1, 0.0), (5.2, 0.0), (5.3, 0.0), (5.5, 0.0), (5.6, -0.05)",
            "(5.0, 0.0)\n(5.1, 0.0)\n(5.2, 0.0)\n(5.3, 0.0)\n(5.5, 0.0)\n(5.6, -0.0",
            "<think>the light is red so",
        ] {
            let p = lenient(text);
            assert_eq!(
                (p.status, p.failure),
                (Status::Failed, Failure::Truncated),
                "{text}"
            );
            assert!(p.reason.starts_with("truncated"));
        }
        // a correction cut off after a complete list is truncated too
        let p = lenient(&format!("{EXACT} Wait: [(5.0, 0.0), (5.1,"));
        assert_eq!(p.failure, Failure::Truncated);
        // a correction cut off inside a number's exponent is truncated too (`0.0e` lexes as a word)
        for cut in ["[(0.000000e", "[(5.0, 1e-", "[(5.0e"] {
            let p = lenient(&format!("{EXACT} {cut}"));
            assert_eq!(p.failure, Failure::Truncated, "{cut}");
        }
        // an unclosed parenthesis of prose is not
        let p = lenient(&format!("{EXACT} (this keeps the lane"));
        assert_eq!(p.status, Status::Corrected);
        let p = lenient(&format!("{EXACT} (see 2nd"));
        assert_eq!(p.status, Status::Corrected);
    }

    #[test]
    fn lists_of_other_lengths_are_not_candidates() {
        let seven = "[(1,0),(2,0),(3,0),(4,0),(5,0),(6,0),(7,0)]";
        let p = lenient(seven);
        assert_eq!(p.status, Status::Failed);
        assert!(p.reason.contains("found lists of 7 pairs"), "{}", p.reason);
        let p = lenient(&format!(
            "{EXACT} e.g. the first two [(5.0, 0.01), (5.5, 0.0)]"
        ));
        assert_eq!(p.values.unwrap(), SIX.to_vec());
    }

    #[test]
    fn json_objects_are_read() {
        let p = lenient(
            r#"{"actions": [[5.0, 0.01], [5.5, 0.0], [6.0, -0.02], [6.5, 0.0], [7.0, 0.0], [7.5, 0.003]]}"#,
        );
        assert_eq!(p.values.unwrap(), SIX.to_vec());
        let keyed: Vec<String> = SIX
            .chunks(2)
            .map(|p| format!(r#"{{"curvature": {}, "speed": {}}}"#, p[1], p[0]))
            .collect();
        let p = lenient(&format!("[{}]", keyed.join(", ")));
        assert_eq!(p.values.unwrap(), SIX.to_vec());
        assert!(p.reason.contains("read by their keys"), "{}", p.reason);
        let p = lenient(&format!(
            "[{}]",
            SIX.chunks(2)
                .map(|p| format!("(c={}, v={})", p[1], p[0]))
                .collect::<Vec<_>>()
                .join(", ")
        ));
        assert_eq!(p.values.unwrap(), SIX.to_vec());
    }

    #[test]
    fn non_finite_never_passes() {
        let p = lenient(&EXACT.replace("0.003", "nan"));
        assert_eq!((p.status, p.failure), (Status::Failed, Failure::Format));
        assert!(p.reason.contains("non-finite curvature"), "{}", p.reason);
        let p = lenient(&EXACT.replace("7.5", "1e999"));
        assert_eq!(p.status, Status::Failed);
        let p = lenient(&list(&[("5.0", "1/0"); 6]));
        assert!(p.reason.contains("non-finite"), "{}", p.reason);
    }

    #[test]
    fn unicode_minus_is_corrected() {
        let p = lenient(&EXACT.replace("-0.02", "\u{2212}0.02"));
        assert_eq!(p.status, Status::Corrected);
        assert_eq!(p.values.unwrap()[5], -0.02);
        assert!(p.reason.contains("unicode minus"), "{}", p.reason);
    }

    #[test]
    fn huge_values_are_named_in_short_scientific_notation() {
        let p = lenient(&list(&[("1e308", "0"); 6]));
        assert_eq!(p.reason, "speed 1e308 at step 1 outside [-10, 50] m/s");
        let p = lenient(&list(&[("5", "-2.5e300"); 6]));
        assert_eq!(p.reason, "curvature -2.5e300 at step 1 outside [-1, 1] 1/m");
        assert_eq!(
            (short(5254.0), short(-0.02), short(0.0), short(3e-9)),
            ("5254".into(), "-0.02".into(), "0".into(), "3e-9".into())
        );
    }

    #[test]
    fn plausibility_gate_and_no_limits() {
        let text = list(&[("60", "0"); 6]);
        assert_eq!(lenient(&text).failure, Failure::Implausible);
        let p = Parser::new().parse(&text, 6, Mode::Lenient, &Limits::NONE);
        assert_eq!(p.status, Status::Ok);
        assert!(Limits::new(Some((1.0, 1.0)), None).is_err());
        assert!(Limits::new(None, Some(0.0)).is_err());
        assert!(Limits::new(Some((f64::NAN, 1.0)), None).is_err());
    }

    #[test]
    fn hostile_inputs_terminate() {
        let digits = "9".repeat(1 << 20);
        assert_eq!(lenient(&digits).status, Status::Failed);
        let nested = "[".repeat(100_000) + &"]".repeat(100_000);
        assert_eq!(lenient(&nested).status, Status::Failed);
        let open = "(".repeat(100_000) + "1";
        assert_eq!(lenient(&open).failure, Failure::Truncated);
        assert_eq!(lenient("").reason, "empty answer");
        let think = "<think>".repeat(10_000) + &"</think>".repeat(10_000);
        assert_eq!(lenient(&think).status, Status::Failed);
    }

    #[test]
    fn fuzz_fragments_in_every_mode() {
        // deterministic xorshift over fragments that build brackets, numbers, tags and junk
        const FRAGMENTS: &[&str] = &[
            "(",
            ")",
            "[",
            "]",
            "{",
            "}",
            ",",
            ";",
            " ",
            "\n",
            "-",
            "+",
            "*",
            "/",
            ".",
            "\u{2212}",
            "e",
            "0",
            "1",
            "5.0",
            "0.01",
            "0001",
            "3.7640.002",
            "nan",
            "<think>",
            "</think>",
            "\u{25c1}think\u{25b7}",
            "v1 =",
            "m/s",
            "1/m",
            "\"v\": ",
            "\"c\": ",
            "3 seconds",
            "1. ",
            "1) ",
            "\u{0}",
            "κ",
            "é",
            "#",
            "\\",
            "0x1F",
            "1_0",
            "```",
            "\r\n",
            "\t",
            "\x0c",
        ];
        let mut state = 0x2545_F491_4F6C_DD1D_u64;
        let mut next = || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            state
        };
        let mut parser = Parser::new();
        let mut out = vec![0.0; 12];
        for _ in 0..20_000 {
            let len = (next() % 60) as usize;
            let text: String = (0..len)
                .map(|_| FRAGMENTS[(next() % FRAGMENTS.len() as u64) as usize])
                .collect();
            for mode in [Mode::Strict, Mode::Lenient, Mode::Paper, Mode::Json] {
                let o = parser.parse_into(&text, 6, mode, &Limits::DEFAULT, None, &mut out);
                assert_eq!(
                    o.failure == Failure::None,
                    o.status != Status::Failed,
                    "{text:?}"
                );
                assert_eq!(
                    o.reason.is_empty(),
                    o.status == Status::Ok,
                    "{text:?} {mode:?}"
                );
                if o.status == Status::Failed {
                    assert!(out.iter().all(|v| v.is_nan()));
                } else {
                    assert!(out.iter().all(|v| v.is_finite()), "{text:?} {mode:?}");
                }
            }
        }
    }

    #[test]
    fn batch_layout_and_unknown_mode() {
        let (values, status, failure, reasons) = parse_batch(
            &["[(1,2),(3,4),(5,6),(7,8),(9,10),(11,12)]", "nope"],
            6,
            Mode::Lenient,
            &Limits::NONE,
            None,
        )
        .unwrap();
        assert_eq!(failure, vec![0, 3]);
        assert_eq!(values.len(), 24);
        assert_eq!(values[11], 12.0);
        assert!(values[12].is_nan());
        assert_eq!(status, vec![0, 2]);
        assert!(reasons[0].is_empty() && !reasons[1].is_empty());
        assert!(Mode::from_name("fuzzy").is_err());
        assert!(parse_batch(&["x"], 0, Mode::Lenient, &Limits::NONE, None).is_err());
        assert!(parse_batch(&["x"], 6, Mode::Lenient, &Limits::NONE, Some(&[0.0; 11])).is_err());
    }
}
