//! The lenient reading of an answer: the last complete list of `n` bracketed pairs.
//!
//! One pass over the tokens with an explicit stack of open brackets (no recursion):
//!
//! * A **pair** is one bracketed group without nested groups whose content is exactly
//!   two values: numbers (`5.0`, `-0.02`, `3e-3`, `−0.02`), or a simple expression of
//!   two numbers (`7.2-0.5`, `1/50`; evaluated, and the reason says so), separated by
//!   `,` or `;` (or by spaces when there is no separator: `(5.0 0.01)`). Units (`m/s`,
//!   `1/m`) are skipped. A group with one speed key and one curvature key
//!   (`{"v": 5.0, "c": 0.01}`, `(v=5.0, c=0.01)`) is a pair too, read by key.
//! * A group that looks numeric but is not two readable values — a fused number
//!   (`3.7640.002`), leading zeros (`0001`), one or three values, stray symbols — is a
//!   **bad pair**: if it belongs to the chosen list, the answer fails with a reason
//!   naming it. Pairs are never re-formed across groups.
//! * A **list** is a bracketed group whose direct children include pairs, or a run of
//!   pairs outside any bracket (one per line, numbered, bulleted…) that is not broken
//!   by prose. The answer is the **last** list (by where it ends) with exactly `n`
//!   pairs; lists with another count are not candidates.
//! * A text that ends inside a bracket holding pairs, or inside a group without words
//!   (`(5.6, -0.0`, a bare `[`), is **truncated**.
//! * Only a text with no pair-like group at all falls back to its standalone numbers
//!   (outside brackets; labels such as `v1 =` and horizon prose such as `3 seconds`
//!   are not numbers), and only when there are exactly `2n` of them.

use crate::lexer::{BadNum, Kind, Token};

/// What the lenient reading found.
#[derive(Debug, Clone, PartialEq)]
pub enum Reading {
    /// Values written; notes say what was not plain (may be empty).
    Found(Vec<String>),
    /// The answer ends inside a list or pair.
    Truncated(String),
    /// Nothing usable; the reason says why.
    Failed(String),
}

/// Why a pair-like group is not a pair.
#[derive(Debug, Clone, Copy, PartialEq)]
enum BadPair {
    Number(BadNum, usize, usize),
    Count(usize),
    Symbols,
    Expression,
    Keys,
}

#[derive(Debug, Clone, Copy)]
struct Pair {
    value: Result<(f64, f64), BadPair>,
    expr: bool,
    unicode: bool,
    keyed: bool,
    pos: usize,
    end: usize,
}

/// A leaf group (no nested groups), classified.
enum Leaf {
    /// No numbers and no words, or only label words (`(v1, κ1)`).
    Label,
    /// Words: prose in brackets.
    Prose,
    /// Four or more values: a flat list, not pairs.
    Flat,
    Pair(Pair),
}

/// An open bracket.
struct Frame {
    open: usize, // token index
    brace: bool,
    leaf: bool,
    /// Direct content other than pairs (words, numbers, groups) — a container
    /// holding one pair and nothing else is that pair (`((5.0, 0.01))`).
    other: bool,
    stray: Option<usize>, // a number directly in the list: its token index
    pairs_start: usize,
}

/// The best candidate so far: the list that ends last with exactly `n` pairs.
struct Best {
    start: usize,
    end: usize,
    bad: Option<(usize, Pair)>,
    stray: Option<usize>,
    explicit: bool,
    unicode: bool,
    keyed: bool,
}

/// Buffers reused from one answer to the next.
#[derive(Default)]
pub struct Lenient {
    pairs: Vec<Pair>,
    stack: Vec<Frame>,
    top_numbers: Vec<f64>,
    other_counts: Vec<usize>,
    expr: Vec<usize>,
}

impl Lenient {
    /// Read `tokens` (of `text`) leniently for `n` pairs, writing `2n` values into `out`.
    pub fn read(&mut self, tokens: &[Token], text: &str, n: usize, out: &mut [f64]) -> Reading {
        self.pairs.clear();
        self.stack.clear();
        self.top_numbers.clear();
        self.other_counts.clear();
        self.expr.clear();
        Scan {
            tokens,
            text,
            n,
            out,
            pairs: &mut self.pairs,
            stack: &mut self.stack,
            best: None,
            best_expr: &mut self.expr,
            candidates: 0,
            other_counts: &mut self.other_counts,
            pair_like: 0,
            run_broken: false,
            top_numbers: &mut self.top_numbers,
            top_bad: None,
        }
        .run()
    }
}

struct Scan<'a> {
    tokens: &'a [Token],
    text: &'a str,
    n: usize,
    out: &'a mut [f64],
    pairs: &'a mut Vec<Pair>,
    stack: &'a mut Vec<Frame>,
    best: Option<Best>,
    /// the pairs of the best candidate that were expressions (1-based)
    best_expr: &'a mut Vec<usize>,
    candidates: usize,
    /// pair counts of lists that were not candidates (for the failure reason)
    other_counts: &'a mut Vec<usize>,
    pair_like: usize,
    /// the top-level run: whether prose broke it since its last pair
    run_broken: bool,
    top_numbers: &'a mut Vec<f64>,
    top_bad: Option<usize>,
}

impl Scan<'_> {
    fn snippet(&self, pos: usize, end: usize) -> String {
        let s = &self.text[pos..end];
        if s.chars().count() <= 40 {
            s.to_owned()
        } else {
            s.chars().take(37).collect::<String>() + "..."
        }
    }

    /// Offer a finished list: `pairs[start..]`, ending at byte `end`.
    fn offer(&mut self, start: usize, span: (usize, usize), explicit: bool, stray: Option<usize>) {
        let (pos, end) = span;
        let count = self.pairs.len() - start;
        if count < self.n.min(2) {
            return;
        }
        if count != self.n {
            if self.other_counts.len() < 8 {
                self.other_counts.push(count);
            }
            return;
        }
        self.candidates += 1;
        if self.best.as_ref().is_some_and(|b| b.end > end) {
            return;
        }
        let mut best = Best {
            start: pos,
            end,
            bad: None,
            stray,
            explicit,
            unicode: false,
            keyed: false,
        };
        self.best_expr.clear();
        for (k, p) in self.pairs[start..].iter().enumerate() {
            match p.value {
                Ok((v, c)) => {
                    self.out[2 * k] = v;
                    self.out[2 * k + 1] = c;
                }
                Err(_) => {
                    if best.bad.is_none() {
                        best.bad = Some((k, *p));
                    }
                }
            }
            if p.expr {
                self.best_expr.push(k + 1);
            }
            best.unicode |= p.unicode;
            best.keyed |= p.keyed;
        }
        self.best = Some(best);
    }

    /// Finish the run of pairs outside any bracket.
    fn end_run(&mut self) {
        if let (Some(first), Some(last)) = (self.pairs.first(), self.pairs.last()) {
            let span = (first.pos, last.end);
            self.offer(0, span, false, None);
            self.pairs.clear();
        }
    }

    fn run(mut self) -> Reading {
        let tokens = self.tokens;
        for (i, t) in tokens.iter().enumerate() {
            match t.kind {
                Kind::Open(b) => {
                    if let Some(parent) = self.stack.last_mut() {
                        parent.leaf = false;
                    }
                    self.stack.push(Frame {
                        open: i,
                        brace: b == b'{',
                        leaf: true,
                        other: false,
                        stray: None,
                        pairs_start: self.pairs.len(),
                    });
                }
                Kind::Close(_) => {
                    // a closer with nothing open (`1)` in prose) is ignored
                    if let Some(frame) = self.stack.pop() {
                        self.close(frame, i);
                    }
                }
                _ => self.content(i, t),
            }
        }
        // does the text end inside a list or a pair?
        let depth = self.stack.len();
        let truncated = (0..depth).any(|d| {
            let f = &self.stack[d];
            let own_end = self
                .stack
                .get(d + 1)
                .map_or(self.pairs.len(), |g| g.pairs_start);
            let holds_pairs = own_end > f.pairs_start;
            holds_pairs || (d + 1 == depth && f.leaf && self.looks_unfinished(f.open + 1))
        });
        if truncated {
            return Reading::Truncated("truncated: the answer ends inside a list".to_owned());
        }
        if let Some(first) = self.stack.first() {
            // only the pairs before the first unclosed bracket form the top-level run
            let top = first.pairs_start;
            self.pairs.truncate(top);
        }
        self.end_run();
        self.verdict()
    }

    /// A token outside brackets, or directly inside the innermost open bracket.
    fn content(&mut self, i: usize, t: &Token) {
        match self.stack.last_mut() {
            Some(frame) => match t.kind {
                Kind::Num { .. } | Kind::Bad(_) => {
                    frame.other = true;
                    frame.stray.get_or_insert(i);
                }
                Kind::Comma | Kind::Semicolon | Kind::Unit => {}
                _ => frame.other = true,
            },
            None => match t.kind {
                Kind::Num { value, .. } => {
                    self.top_numbers.push(value);
                    self.run_broken = true;
                }
                Kind::Bad(_) => {
                    self.top_bad.get_or_insert(i);
                    self.run_broken = true;
                }
                Kind::Word { label: false } => self.run_broken = true,
                _ => {}
            },
        }
    }

    fn close(&mut self, frame: Frame, close: usize) {
        let tokens = self.tokens;
        let pos = tokens[frame.open].pos;
        let end = tokens[close].end;
        // what this group is to its parent
        let mut is_label = false;
        let as_pair = if frame.leaf {
            let inner = &tokens[frame.open + 1..close];
            let leaf = if frame.brace {
                keyed_pair(inner, self.text, pos, end)
            } else {
                classify(inner, self.text, pos, end)
            };
            match leaf {
                Leaf::Pair(p) => {
                    self.pair_like += 1;
                    Some(p)
                }
                Leaf::Label => {
                    is_label = true;
                    None
                }
                Leaf::Prose | Leaf::Flat => None,
            }
        } else {
            let own = self.pairs.len() - frame.pairs_start;
            let wrapped = if own == 1 && !frame.other {
                // redundant brackets around one pair: `((5.0, 0.01))`
                self.pairs.pop()
            } else {
                self.offer(frame.pairs_start, (pos, end), true, frame.stray);
                None
            };
            self.pairs.truncate(frame.pairs_start);
            wrapped
        };
        match self.stack.last_mut() {
            Some(parent) => match as_pair {
                Some(p) => self.pairs.push(p),
                None => parent.other = true,
            },
            None => match as_pair {
                Some(p) => {
                    if self.run_broken {
                        self.end_run();
                        self.run_broken = false;
                    }
                    self.pairs.push(p);
                }
                None if is_label => {}
                None => self.run_broken = true,
            },
        }
    }

    /// Whether the tokens from `from` to the end (the innermost unclosed group's
    /// content) look like a cut-off pair or list: no words, perhaps numbers.
    fn looks_unfinished(&self, from: usize) -> bool {
        let rest = &self.tokens[from.min(self.tokens.len())..];
        // a number cut inside its exponent (`0.5e`, `2e-`) lexes as a word glued to a number:
        // such a word, followed by nothing but operators up to the very end of the text, is no prose
        let cut_exponent = |k: usize| {
            let t = rest[k];
            self.text[t.pos..t.end].starts_with(|c: char| {
                c.is_ascii_digit() || matches!(c, '.' | '-' | '+' | '\u{2212}')
            }) && rest[k + 1..]
                .iter()
                .all(|u| matches!(u.kind, Kind::Op { .. }))
                && rest.last().is_some_and(|u| u.end == self.text.len())
        };
        !rest
            .iter()
            .enumerate()
            .any(|(k, t)| matches!(t.kind, Kind::Word { .. } | Kind::Label) && !cut_exponent(k))
    }

    fn verdict(self) -> Reading {
        let n = self.n;
        if let Some(best) = &self.best {
            if let Some((k, p)) = best.bad {
                return Reading::Failed(self.bad_reason(k, &p));
            }
            if let Some(i) = best.stray {
                let t = self.tokens[i];
                return Reading::Failed(format!(
                    "a number outside the pairs of the list: {:?} at position {}",
                    self.snippet(t.pos, t.end),
                    t.pos
                ));
            }
            let mut notes = Vec::new();
            if self.candidates > 1 {
                notes.push(format!(
                    "took the last of {} candidate lists",
                    self.candidates
                ));
            }
            if !best.explicit {
                notes.push("pairs without an enclosing list".to_owned());
            }
            let whole = (self.tokens[0].pos, self.tokens[self.tokens.len() - 1].end);
            if best.explicit && (best.start, best.end) != whole {
                notes.push("text around the list".to_owned());
            }
            if !self.best_expr.is_empty() {
                let which: Vec<String> = self.best_expr.iter().map(usize::to_string).collect();
                notes.push(format!("expression evaluated (pair {})", which.join(", ")));
            }
            if best.keyed {
                notes.push("pairs read by their keys (speed, curvature)".to_owned());
            }
            if best.unicode {
                notes.push("unicode minus read as '-'".to_owned());
            }
            return Reading::Found(notes);
        }
        if self.pair_like > 0 || !self.other_counts.is_empty() {
            let counts: Vec<String> = self.other_counts.iter().map(usize::to_string).collect();
            return Reading::Failed(if counts.is_empty() {
                format!(
                    "{} bracketed pair(s) but no list of {n} pairs",
                    self.pair_like
                )
            } else {
                format!(
                    "no list of {n} pairs (found lists of {} pairs)",
                    counts.join(", ")
                )
            });
        }
        if let Some(i) = self.top_bad {
            let t = self.tokens[i];
            return Reading::Failed(format!(
                "no bracketed pairs, and {:?} at position {} is not a number",
                self.snippet(t.pos, t.end),
                t.pos
            ));
        }
        let count = self.top_numbers.len();
        if count == 2 * n {
            self.out.copy_from_slice(self.top_numbers);
            return Reading::Found(vec![format!(
                "read {} standalone numbers (no bracketed pairs)",
                2 * n
            )]);
        }
        Reading::Failed(format!(
            "no bracketed pairs, and {count} standalone number(s) where exactly {} are needed",
            2 * n
        ))
    }

    fn bad_reason(&self, k: usize, p: &Pair) -> String {
        let group = self.snippet(p.pos, p.end);
        let what = match p.value {
            Err(BadPair::Number(kind, pos, end)) => {
                let num = self.snippet(pos, end);
                match kind {
                    BadNum::Fused => {
                        format!("{num} is not a number (numbers run together: a lost comma?)")
                    }
                    BadNum::LeadingZeros => {
                        format!("{num} has leading zeros (a lost decimal point?)")
                    }
                }
            }
            Err(BadPair::Count(c)) => format!("holds {c} value(s), not 2"),
            Err(BadPair::Symbols) => "is not two numbers".to_owned(),
            Err(BadPair::Expression) => "is not two numbers or simple expressions".to_owned(),
            Err(BadPair::Keys) => "has no single speed and curvature key".to_owned(),
            Ok(_) => "is fine".to_owned(),
        };
        format!("pair {} {group} {what}", k + 1)
    }
}

/// Classify a round or square group without nested groups.
fn classify(inner: &[Token], text: &str, pos: usize, end: usize) -> Leaf {
    let mut nums = 0;
    let mut seps = 0;
    let mut words = false;
    let mut label_words = false;
    let mut symbols = false;
    let mut bad: Option<(BadNum, usize, usize)> = None;
    let mut trailing_sep = false;
    for t in inner {
        trailing_sep = false;
        match t.kind {
            Kind::Num { .. } => nums += 1,
            Kind::Bad(b) => {
                nums += 1;
                bad.get_or_insert((b, t.pos, t.end));
            }
            Kind::Comma | Kind::Semicolon => {
                seps += 1;
                trailing_sep = true;
            }
            Kind::Word { label: true } | Kind::Label => label_words = true,
            Kind::Word { label: false } => words = true,
            Kind::Op { .. } | Kind::Unit => {}
            Kind::Other => symbols = true,
            Kind::Open(_) | Kind::Close(_) => {}
        }
    }
    if words {
        return Leaf::Prose;
    }
    if label_words && nums > 0 {
        // `(v=5.0, c=0.01)`, `(v1: 5.0, κ1: 0.01)`: read by the keys, else prose
        return keyed_pair(inner, text, pos, end);
    }
    if nums == 0 {
        return if symbols { Leaf::Prose } else { Leaf::Label };
    }
    let items = if seps > 0 {
        seps + 1 - usize::from(trailing_sep)
    } else {
        nums
    };
    if items >= 4 {
        return Leaf::Flat;
    }
    let mut pair = Pair {
        value: Err(BadPair::Symbols),
        expr: false,
        unicode: false,
        keyed: false,
        pos,
        end,
    };
    pair.value = if let Some((b, p, e)) = bad {
        Err(BadPair::Number(b, p, e))
    } else if symbols {
        Err(BadPair::Symbols)
    } else if items != 2 {
        Err(BadPair::Count(items))
    } else if seps == 0 {
        // `(5.0 0.01)`: two numbers and nothing else
        let mut values = inner.iter().filter_map(|t| match t.kind {
            Kind::Num { value, plain, .. } => Some((value, plain)),
            _ => None,
        });
        match (values.next(), values.next()) {
            (Some((v, pv)), Some((c, pc)))
                if !inner.iter().any(|t| matches!(t.kind, Kind::Op { .. })) =>
            {
                pair.unicode = !(pv && pc);
                Ok((v, c))
            }
            _ => Err(BadPair::Count(1)),
        }
    } else {
        let is_sep = |t: &Token| matches!(t.kind, Kind::Comma | Kind::Semicolon);
        let split = inner.iter().position(is_sep).unwrap_or(inner.len());
        let rest = &inner[(split + 1).min(inner.len())..];
        let rest = &rest[..rest.iter().position(is_sep).unwrap_or(rest.len())];
        match (expression(&inner[..split]), expression(rest)) {
            (Some(a), Some(b)) => {
                pair.expr = a.expr || b.expr;
                pair.unicode = a.unicode || b.unicode;
                Ok((a.value, b.value))
            }
            _ => Err(BadPair::Expression),
        }
    };
    Leaf::Pair(pair)
}

struct Value {
    value: f64,
    expr: bool,
    unicode: bool,
}

/// One item of a pair: `[±] a [op b]`, or `a ±b` (a signed number after a number).
fn expression(item: &[Token]) -> Option<Value> {
    let mut toks = item.iter().filter(|t| t.kind != Kind::Unit).map(|t| t.kind);
    let mut unicode = false;
    let mut first = toks.next()?;
    let mut negate = false;
    if let Kind::Op { op, plain } = first {
        if op != b'-' && op != b'+' {
            return None;
        }
        negate = op == b'-';
        unicode |= !plain;
        first = toks.next()?;
    }
    let Kind::Num {
        value: a, plain, ..
    } = first
    else {
        return None;
    };
    unicode |= !plain;
    let a = if negate { -a } else { a };
    let value = match (toks.next(), toks.next(), toks.next()) {
        (None, _, _) => {
            return Some(Value {
                value: a,
                expr: false,
                unicode,
            })
        }
        (
            Some(Kind::Num {
                value: b,
                plain,
                signed: true,
            }),
            None,
            _,
        ) => {
            unicode |= !plain;
            a + b
        }
        (
            Some(Kind::Op { op, plain }),
            Some(Kind::Num {
                value: b,
                plain: pb,
                ..
            }),
            None,
        ) => {
            unicode |= !(plain && pb);
            match op {
                b'+' => a + b,
                b'-' => a - b,
                b'*' => a * b,
                _ => a / b,
            }
        }
        _ => return None,
    };
    Some(Value {
        value,
        expr: true,
        unicode,
    })
}

/// A JSON-like object `{"speed": v, "curvature": c}` (keys in any order) without nested groups.
fn keyed_pair(inner: &[Token], text: &str, pos: usize, end: usize) -> Leaf {
    let mut speed = None;
    let mut curvature = None;
    let mut extra = false;
    let mut key: Option<bool> = None;
    for t in inner {
        match t.kind {
            Kind::Word { .. } => key = key_kind(&text[t.pos..t.end]),
            Kind::Num { value, .. } => {
                match key {
                    Some(true) if speed.is_none() => speed = Some(value),
                    Some(false) if curvature.is_none() => curvature = Some(value),
                    Some(_) => extra = true,
                    None => {}
                }
                key = None;
            }
            Kind::Bad(_) => extra |= key.is_some(),
            Kind::Comma => key = None,
            _ => {}
        }
    }
    if speed.is_none() && curvature.is_none() && !extra {
        return Leaf::Prose;
    }
    let value = match (speed, curvature, extra) {
        (Some(v), Some(c), false) => Ok((v, c)),
        _ => Err(BadPair::Keys),
    };
    Leaf::Pair(Pair {
        value,
        expr: false,
        unicode: false,
        keyed: true,
        pos,
        end,
    })
}

/// `Some(true)` for a speed key (`v`, `speed`, `velocity`), `Some(false)` for a
/// curvature key (`c`, `k`, `κ`, `kappa`, `curvature`), else `None`.
fn key_kind(word: &str) -> Option<bool> {
    let lower = word.to_lowercase();
    let stem = lower.trim_end_matches(|c: char| c.is_ascii_digit() || c == '_');
    match stem {
        "v" | "speed" | "velocity" | "vel" => Some(true),
        "c" | "k" | "κ" | "kappa" | "curvature" | "curv" => Some(false),
        _ => None,
    }
}

/// Reasoning blocks found in an answer.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Blocks {
    /// How many blocks were removed.
    pub removed: usize,
    /// The answer ends inside one.
    pub unclosed: bool,
}

const BLOCK_NAMES: &[&str] = &["think", "thinking", "reasoning", "reflection"];

/// A reasoning tag at byte `i` (`<think>`, `</think>`, `◁think▷`, `◁/think▷`, …):
/// (is a closing tag, end of the tag).
fn tag_at(bytes: &[u8], i: usize) -> Option<(bool, usize)> {
    let mut j = match bytes.get(i..i + 3) {
        Some([0xE2, 0x97, 0x81]) => i + 3, // ◁
        _ if bytes.get(i) == Some(&b'<') => i + 1,
        _ => return None,
    };
    let close = bytes.get(j) == Some(&b'/');
    j += usize::from(close);
    let name_end = j + bytes[j.min(bytes.len())..]
        .iter()
        .take(12)
        .take_while(|b| b.is_ascii_alphabetic())
        .count();
    let name = &bytes[j..name_end];
    if !BLOCK_NAMES
        .iter()
        .any(|n| n.as_bytes().eq_ignore_ascii_case(name))
    {
        return None;
    }
    match bytes.get(name_end..name_end + 3) {
        _ if bytes.get(name_end) == Some(&b'>') => Some((close, name_end + 1)),
        Some([0xE2, 0x96, 0xB7]) => Some((close, name_end + 3)), // ▷
        _ => None,
    }
}

/// The byte ranges of `text` outside reasoning blocks (`<think>…</think>`,
/// `<thinking>`, `<reasoning>`, `<reflection>`, `◁think▷…◁/think▷`, any case). A
/// closing tag before any opening one ends a block that began with the answer
/// (templates that open the block themselves). One pass.
pub fn answer_ranges(text: &str, ranges: &mut Vec<(usize, usize)>) -> Blocks {
    ranges.clear();
    let bytes = text.as_bytes();
    let mut blocks = Blocks::default();
    if !bytes.iter().any(|&b| b == b'<' || b == 0xE2) {
        ranges.push((0, bytes.len()));
        return blocks;
    }
    let mut seg_start = 0;
    let mut inside = false;
    let mut first = true;
    let mut i = 0;
    while i < bytes.len() {
        let Some((close, end)) = tag_at(bytes, i) else {
            i += 1;
            continue;
        };
        if first && close {
            blocks.removed += 1; // the block opened before the answer began
            seg_start = end;
        } else if !inside && !close {
            ranges.push((seg_start, i));
            inside = true;
            blocks.removed += 1;
        } else if inside && close {
            seg_start = end;
            inside = false;
        }
        first = false;
        i = end;
    }
    if inside {
        blocks.unclosed = true;
    } else {
        ranges.push((seg_start, bytes.len()));
    }
    ranges.retain(|&(a, b)| a < b);
    blocks
}
