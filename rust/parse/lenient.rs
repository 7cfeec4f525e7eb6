//! The lenient reading of an answer: the one list of `n` actions its structure gives.
//!
//! One pass over the tokens with an explicit stack of open brackets (no recursion):
//!
//! * A **pair** is one bracketed group without nested groups whose content is exactly
//!   two values: numbers (`5.0`, `-0.02`, `3e-3`, `−0.02`), or a simple expression of
//!   two numbers (`7.2+0.5`, `1/50`, `0.5*0.02`; evaluated, and the reason says so),
//!   separated by `,` or `;` (or by spaces when there is no separator: `(5.0 0.01)`).
//!   Units (`m/s`, `1/m`) are skipped. A group with one speed key and one curvature key
//!   (`{"v": 5.0, "c": 0.01}`, `(v=5.0, c=0.01)`) is a pair too, read by key.
//! * A group that looks numeric but is not two readable values — a fused number
//!   (`3.7640.002`), leading zeros (`0001`), a doubled sign (`--0.01`), a range or a
//!   subtraction (`4.5-5.0`: which is meant is unknown), one or three values, stray
//!   symbols — is a **bad pair**: if it belongs to the chosen list, the answer fails
//!   with a reason naming it. Pairs are never re-formed across groups.
//! * A **list** is a bracketed group whose direct children include pairs, or a run of
//!   pairs outside any bracket (one per line, numbered, bulleted…) that is not broken
//!   by prose. A bracketed group of `n` items `v c` (`[11.4 0.0, 11.5 0.0, …]`) is a
//!   list too, and so is a flat bracketed list of exactly `2n` numbers `[v1, c1, …]`.
//!   Two flat lists of `n` numbers labelled as speeds and curvatures (`"speeds": [...]`,
//!   `v: [...]`) form one list. Lists with another count are not candidates.
//! * **The candidates must agree.** A candidate equal to the history the prompt gave
//!   is a quotation, skipped when another candidate exists, only where its own sentence
//!   says it is the past (`past`, `previous`, `history` before it, no sentence end
//!   between); without such a word it is a candidate like any other (keeping one's pace
//!   is a common answer), and alone it is the answer. Identical candidates are one.
//!   Several different candidates are **ambiguous** unless a correction or final-answer
//!   cue (`Wait`, `Actually`, `Correction`, `Revised`, `Final answer`, …) stands after an
//!   earlier one and before the last: then the candidates after the last such cue must
//!   agree. Cues win over the history rule: a history-equal list whose sentence holds both
//!   a past word and a cue is no quotation, and is ambiguous beside a different list.
//! * A text that ends inside a bracket holding pairs, or inside a group without words
//!   (`(5.6, -0.0`, a bare `[`), is **truncated**.
//! * Only a text with no pair-like group at all falls back to its standalone numbers
//!   (outside brackets; labels such as `v1 =` and horizon prose such as `3 seconds`
//!   are not numbers), and only when their layout pairs them: labelled as speeds and
//!   curvatures (`Speeds: … Curvatures: …`, `v1 = …, c1 = …`), a table under a speed
//!   and curvature header, or one pair per line. Otherwise `2n` numbers are ambiguous.

use super::lexer::{BadNum, Kind, Token};

/// What the lenient reading found.
#[derive(Debug, Clone, PartialEq)]
pub enum Reading {
    /// Values written; notes say what was not plain (may be empty).
    Found(Vec<String>),
    /// The answer ends inside a list or pair.
    Truncated(String),
    /// Readings disagree (several different lists, a range, an unknown pairing).
    Ambiguous(String),
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
    /// `a-b`: a range or a subtraction (byte span of the item)
    Range(usize, usize),
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
    /// the speed (true) or curvature (false) key last written directly in this group
    key: Option<bool>,
}

/// How a candidate was written.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Shape {
    Pairs,
    /// `[v c, v c, …]`
    Spaced,
    /// `[v1, c1, v2, c2, …]`
    Flat,
    /// speeds and curvatures as two labelled lists
    Labelled,
    /// standalone numbers (the fallback); the note says how they were paired
    Loose(&'static str),
}

/// A byte span `(start, end)` of the text.
type Span = (usize, usize);

/// A complete reading of `n` actions.
struct Cand {
    start: usize,
    end: usize,
    /// offset of its `2n` values in `Lenient::values`
    values: usize,
    bad: Option<(usize, Pair)>,
    stray: Option<usize>,
    explicit: bool,
    unicode: bool,
    keyed: bool,
    /// its expression pairs (1-based) in `Lenient::expr`
    expr: (usize, usize),
    shape: Shape,
}

impl Cand {
    fn good(&self) -> bool {
        self.bad.is_none() && self.stray.is_none()
    }
}

/// A flat bracketed list of numbers: its values in `Lenient::seq_values`.
#[derive(Debug, Clone, Copy)]
struct Seq {
    pos: usize,
    end: usize,
    off: usize,
    len: usize,
    unicode: bool,
}

/// A token outside every bracket, kept for the standalone-number fallback.
#[derive(Debug, Clone, Copy)]
enum Loose {
    Num(f64, usize, usize),
    /// a speed (true) or curvature (false) key word
    Key(bool, usize),
    Prose(usize),
    /// `-` not attached to a number, at this byte
    Minus(usize),
    /// `;`: ends a group like a line break
    Break(usize),
}

/// Buffers reused from one answer to the next.
#[derive(Default)]
pub struct Lenient {
    pairs: Vec<Pair>,
    stack: Vec<Frame>,
    cands: Vec<Cand>,
    values: Vec<f64>,
    expr: Vec<usize>,
    cues: Vec<Span>,
    /// words saying that what follows is the past (`past`, `previous`, `history`): their byte spans
    pasts: Vec<Span>,
    /// sentence ends (`.`, `!`, `?` outside numbers): their bytes
    stops: Vec<usize>,
    /// the candidates' ends, sorted (for the history rule)
    ends: Vec<usize>,
    seq_values: Vec<f64>,
    loose: Vec<Loose>,
    other_counts: Vec<usize>,
    live: Vec<usize>,
}

impl Lenient {
    /// Read `tokens` (of `text`) leniently for `n` pairs, writing `2n` values into `out`.
    /// `history` (`2n` values: the history the prompt printed), when given, marks a
    /// candidate equal to it as a quotation.
    pub fn read(
        &mut self,
        tokens: &[Token],
        text: &str,
        n: usize,
        history: Option<&[f64]>,
        out: &mut [f64],
    ) -> Reading {
        self.pairs.clear();
        self.stack.clear();
        self.cands.clear();
        self.values.clear();
        self.expr.clear();
        self.cues.clear();
        self.pasts.clear();
        self.stops.clear();
        self.seq_values.clear();
        self.loose.clear();
        self.other_counts.clear();
        self.live.clear();
        Scan {
            tokens,
            text,
            n,
            history: history.filter(|h| h.len() == 2 * n),
            out,
            buf: self,
            pair_like: 0,
            run_broken: false,
            top_bad: None,
            top_key: None,
            pending: [None, None],
            unlabelled_seqs: 0,
        }
        .run()
    }
}

struct Scan<'a> {
    tokens: &'a [Token],
    text: &'a str,
    n: usize,
    history: Option<&'a [f64]>,
    out: &'a mut [f64],
    buf: &'a mut Lenient,
    pair_like: usize,
    /// the top-level run: whether prose broke it since its last pair
    run_broken: bool,
    top_bad: Option<usize>,
    /// the speed / curvature key last written outside brackets
    top_key: Option<bool>,
    /// a labelled list of `n` speeds \[0\] or curvatures \[1\] waiting for its partner
    pending: [Option<Seq>; 2],
    /// flat lists of `n` numbers without a speed / curvature label
    unlabelled_seqs: usize,
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
    fn offer(
        &mut self,
        start: usize,
        span: (usize, usize),
        explicit: bool,
        stray: Option<usize>,
        shape: Shape,
    ) {
        let (pos, end) = span;
        let count = self.buf.pairs.len() - start;
        if count < self.n.min(2) {
            return;
        }
        if count != self.n {
            if self.buf.other_counts.len() < 8 {
                self.buf.other_counts.push(count);
            }
            return;
        }
        let values = self.buf.values.len();
        let expr_start = self.buf.expr.len();
        let mut cand = Cand {
            start: pos,
            end,
            values,
            bad: None,
            stray,
            explicit,
            unicode: false,
            keyed: false,
            expr: (expr_start, expr_start),
            shape,
        };
        for k in 0..count {
            let p = self.buf.pairs[start + k];
            match p.value {
                Ok((v, c)) => self.buf.values.extend_from_slice(&[v, c]),
                Err(_) => {
                    self.buf.values.extend_from_slice(&[f64::NAN, f64::NAN]);
                    if cand.bad.is_none() {
                        cand.bad = Some((k, p));
                    }
                }
            }
            if p.expr {
                self.buf.expr.push(k + 1);
            }
            cand.unicode |= p.unicode;
            cand.keyed |= p.keyed;
        }
        cand.expr.1 = self.buf.expr.len();
        self.buf.cands.push(cand);
    }

    /// Offer `n` actions given as values (v1, c1, …) already in `Lenient::values` from `values`.
    fn offer_values(&mut self, span: (usize, usize), values: usize, unicode: bool, shape: Shape) {
        let e = self.buf.expr.len();
        self.buf.cands.push(Cand {
            start: span.0,
            end: span.1,
            values,
            bad: None,
            stray: None,
            explicit: !matches!(shape, Shape::Loose(_)),
            unicode,
            keyed: false,
            expr: (e, e),
            shape,
        });
    }

    /// Finish the run of pairs outside any bracket.
    fn end_run(&mut self) {
        if let (Some(first), Some(last)) = (self.buf.pairs.first(), self.buf.pairs.last()) {
            let span = (first.pos, last.end);
            self.offer(0, span, false, None, Shape::Pairs);
            self.buf.pairs.clear();
        }
    }

    fn run(mut self) -> Reading {
        let tokens = self.tokens;
        for (i, t) in tokens.iter().enumerate() {
            match t.kind {
                Kind::Open(b) => {
                    if let Some(parent) = self.buf.stack.last_mut() {
                        parent.leaf = false;
                    }
                    let pairs_start = self.buf.pairs.len();
                    self.buf.stack.push(Frame {
                        open: i,
                        brace: b == b'{',
                        leaf: true,
                        other: false,
                        stray: None,
                        pairs_start,
                        key: None,
                    });
                }
                Kind::Close(_) => {
                    // a closer with nothing open (`1)` in prose) is ignored
                    if let Some(frame) = self.buf.stack.pop() {
                        self.close(frame, i);
                    }
                }
                _ => self.content(i, t),
            }
        }
        // does the text end inside a list or a pair?
        let depth = self.buf.stack.len();
        let truncated = (0..depth).any(|d| {
            let f = &self.buf.stack[d];
            let own_end = self
                .buf
                .stack
                .get(d + 1)
                .map_or(self.buf.pairs.len(), |g| g.pairs_start);
            let holds_pairs = own_end > f.pairs_start;
            holds_pairs || (d + 1 == depth && f.leaf && self.looks_unfinished(f.open + 1))
        });
        if truncated {
            return Reading::Truncated("truncated: the answer ends inside a list".to_owned());
        }
        if let Some(first) = self.buf.stack.first() {
            // only the pairs before the first unclosed bracket form the top-level run
            let top = first.pairs_start;
            self.buf.pairs.truncate(top);
        }
        self.end_run();
        self.verdict()
    }

    /// A token outside brackets, or directly inside the innermost open bracket.
    fn content(&mut self, i: usize, t: &Token) {
        let word = match t.kind {
            Kind::Word { .. } => {
                let w = &self.text[t.pos..t.end];
                if is_cue(w, self.tokens.get(i + 1), self.text) {
                    self.buf.cues.push((t.pos, t.end));
                } else if is_past(w) {
                    self.buf.pasts.push((t.pos, t.end));
                }
                Some(sequence_key(w))
            }
            Kind::Other => {
                if self.text[t.pos..].starts_with(['.', '!', '?']) {
                    self.buf.stops.push(t.pos);
                }
                None
            }
            _ => None,
        };
        match self.buf.stack.last_mut() {
            Some(frame) => match t.kind {
                Kind::Num { .. } | Kind::Bad(_) => {
                    frame.other = true;
                    frame.key = None;
                    frame.stray.get_or_insert(i);
                }
                Kind::Comma | Kind::Semicolon | Kind::Unit => {}
                _ => {
                    frame.other = true;
                    if let Some(Some(k)) = word {
                        frame.key = Some(k);
                    }
                }
            },
            None => match t.kind {
                Kind::Num { value, .. } => {
                    self.buf.loose.push(Loose::Num(value, t.pos, t.end));
                    self.top_key = None;
                    self.run_broken = true;
                }
                Kind::Bad(_) => {
                    self.top_bad.get_or_insert(i);
                    self.run_broken = true;
                }
                Kind::Word { label } => {
                    match word.flatten() {
                        Some(k) => {
                            self.buf.loose.push(Loose::Key(k, t.pos));
                            self.top_key = Some(k);
                        }
                        None if !label => self.buf.loose.push(Loose::Prose(t.pos)),
                        None => {}
                    }
                    if !label {
                        self.run_broken = true;
                    }
                }
                Kind::Op { op: b'-', .. } => self.buf.loose.push(Loose::Minus(t.pos)),
                Kind::Semicolon => self.buf.loose.push(Loose::Break(t.pos)),
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
                Leaf::Flat => {
                    self.flat(inner, pos, end);
                    None
                }
                Leaf::Prose => None,
            }
        } else {
            let own = self.buf.pairs.len() - frame.pairs_start;
            let wrapped = if own == 1 && !frame.other {
                // redundant brackets around one pair: `((5.0, 0.01))`
                self.buf.pairs.pop()
            } else {
                self.offer(
                    frame.pairs_start,
                    (pos, end),
                    true,
                    frame.stray,
                    Shape::Pairs,
                );
                None
            };
            self.buf.pairs.truncate(frame.pairs_start);
            wrapped
        };
        match self.buf.stack.last_mut() {
            Some(parent) => {
                parent.key = None;
                match as_pair {
                    Some(p) => self.buf.pairs.push(p),
                    None => parent.other = true,
                }
            }
            None => {
                self.top_key = None;
                match as_pair {
                    Some(p) => {
                        if self.run_broken {
                            self.end_run();
                            self.run_broken = false;
                        }
                        self.buf.pairs.push(p);
                    }
                    None if is_label => {}
                    None => self.run_broken = true,
                }
            }
        }
    }

    /// A leaf group of four or more values: `[v c, v c, …]` (a list of pairs), a flat
    /// list of `2n` numbers, or a flat list of `n` speeds or curvatures.
    fn flat(&mut self, inner: &[Token], pos: usize, end: usize) {
        let key = match self.buf.stack.last() {
            Some(parent) => parent.key,
            None => self.top_key,
        };
        let has_seps = inner
            .iter()
            .any(|t| matches!(t.kind, Kind::Comma | Kind::Semicolon));
        let off = self.buf.seq_values.len();
        let pairs_start = self.buf.pairs.len();
        let mut per_item: Option<usize> = None; // numbers per item: 1 or 2
        let mut items = 0;
        let mut cur = 0; // numbers in the current item
        let mut span = (pos, pos);
        let mut unicode = false;
        let mut ok = true;
        for t in inner {
            let ends_item = match t.kind {
                Kind::Num { value, plain, .. } => {
                    if cur == 0 {
                        span.0 = t.pos;
                    }
                    span.1 = t.end;
                    cur += 1;
                    unicode |= !plain;
                    self.buf.seq_values.push(value);
                    !has_seps
                }
                Kind::Comma | Kind::Semicolon => {
                    if cur == 0 {
                        ok = false; // an empty item
                    }
                    true
                }
                Kind::Unit => false,
                _ => {
                    ok = false;
                    false
                }
            };
            if !ok {
                break;
            }
            if ends_item {
                if !self.end_flat_item(&mut per_item, &mut cur, span) {
                    ok = false;
                    break;
                }
                items += 1;
            }
        }
        if ok && cur > 0 {
            ok = self.end_flat_item(&mut per_item, &mut cur, span);
            items += 1;
        }
        let n = self.n;
        match per_item {
            Some(2) if ok => self.offer(pairs_start, (pos, end), true, None, Shape::Spaced),
            Some(1) if ok && key.is_none() && items == 2 * n => {
                let values = self.buf.values.len();
                let seq = &self.buf.seq_values[off..off + 2 * n];
                self.buf.values.extend_from_slice(seq);
                self.offer_values((pos, end), values, unicode, Shape::Flat);
            }
            Some(1) if ok && items == n => match key {
                None => self.unlabelled_seqs += 1,
                Some(speeds) => {
                    let seq = Seq {
                        pos,
                        end,
                        off,
                        len: n,
                        unicode,
                    };
                    let (mine, theirs) = if speeds { (0, 1) } else { (1, 0) };
                    match self.pending[theirs].take() {
                        None => {
                            self.pending[mine] = Some(seq);
                            return; // its values wait for the partner
                        }
                        Some(other) => {
                            let (s, c) = if speeds { (seq, other) } else { (other, seq) };
                            let values = self.buf.values.len();
                            for k in 0..s.len.min(c.len) {
                                let v = self.buf.seq_values[s.off + k];
                                let cv = self.buf.seq_values[c.off + k];
                                self.buf.values.extend_from_slice(&[v, cv]);
                            }
                            let span = (s.pos.min(c.pos), s.end.max(c.end));
                            self.offer_values(
                                span,
                                values,
                                s.unicode || c.unicode,
                                Shape::Labelled,
                            );
                        }
                    }
                }
            },
            _ => {}
        }
        self.buf.pairs.truncate(pairs_start);
        self.buf.seq_values.truncate(off);
    }

    /// End an item of a flat group: every item holds the same count (1 or 2) of numbers;
    /// an item of two becomes a pair.
    fn end_flat_item(
        &mut self,
        per_item: &mut Option<usize>,
        cur: &mut usize,
        span: (usize, usize),
    ) -> bool {
        let k = std::mem::take(cur);
        if !matches!(k, 1 | 2) || per_item.is_some_and(|p| p != k) {
            return false;
        }
        *per_item = Some(k);
        if k == 2 {
            let l = self.buf.seq_values.len();
            let (v, c) = (self.buf.seq_values[l - 2], self.buf.seq_values[l - 1]);
            self.buf.pairs.push(Pair {
                value: Ok((v, c)),
                expr: false,
                unicode: false,
                keyed: false,
                pos: span.0,
                end: span.1,
            });
        }
        true
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

    fn cand_values(&self, c: &Cand) -> &[f64] {
        &self.buf.values[c.values..c.values + 2 * self.n]
    }

    fn same(&self, a: usize, b: usize) -> bool {
        let (ca, cb) = (&self.buf.cands[a], &self.buf.cands[b]);
        a == b || (ca.good() && cb.good() && self.cand_values(ca) == self.cand_values(cb))
    }

    fn verdict(mut self) -> Reading {
        let n = self.n;
        if self.buf.cands.is_empty() {
            if self.pair_like > 0 || !self.buf.other_counts.is_empty() {
                let counts: Vec<String> =
                    self.buf.other_counts.iter().map(usize::to_string).collect();
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
            if self.unlabelled_seqs >= 2 {
                return Reading::Ambiguous(format!(
                    "ambiguous: {} lists of {n} numbers, but which holds the speeds and which the \
                     curvatures is unknown (no speed / curvature labels)",
                    self.unlabelled_seqs
                ));
            }
            if let Some(i) = self.top_bad {
                let t = self.tokens[i];
                let what = match t.kind {
                    Kind::Bad(BadNum::DoubledSign) => "has a doubled sign",
                    _ => "is not a number",
                };
                return Reading::Failed(format!(
                    "no bracketed pairs, and {:?} at position {} {what}",
                    self.snippet(t.pos, t.end),
                    t.pos
                ));
            }
            if let Err(r) = self.loose() {
                return r;
            }
        }
        self.select()
    }

    /// Whether candidate `c` is a good list equal to the history the prompt gave.
    fn is_history(&self, c: &Cand) -> bool {
        c.good() && self.history.is_some_and(|h| self.cand_values(c) == h)
    }

    /// What the sentence introducing candidate `ci` says of it: the last past word
    /// (`past`, `previous`, `history`) and the last correction / final-answer cue between
    /// the end of the previous candidate (or of the previous sentence) and its start.
    /// `ends`: every candidate's end, sorted. Binary searches only (positions are recorded
    /// in text order), so an answer of many history-equal lists stays linear-logarithmic.
    fn introduction(&self, ci: usize, ends: &[usize]) -> (Option<Span>, Option<Span>) {
        let start = self.buf.cands[ci].start;
        let before = |sorted: &[usize]| {
            let k = sorted.partition_point(|&x| x < start);
            (k > 0).then(|| sorted[k - 1])
        };
        let prev_end = match ends.partition_point(|&e| e <= start) {
            0 => 0,
            k => ends[k - 1],
        };
        let from = before(&self.buf.stops).map_or(prev_end, |s| prev_end.max(s + 1));
        let within = |spans: &[Span]| {
            let k = spans.partition_point(|&(p, _)| p < start);
            (k > 0 && spans[k - 1].0 >= from).then(|| spans[k - 1])
        };
        (within(&self.buf.pasts), within(&self.buf.cues))
    }

    /// Choose among the candidates (at least one).
    fn select(&mut self) -> Reading {
        let n = self.n;
        // a candidate equal to the history is a quotation where its sentence says it is the past
        // (and no cue there says it is the answer); one with both is contested
        let mut quoted = Vec::new();
        let mut contested = None;
        let mut ends = std::mem::take(&mut self.buf.ends);
        ends.clear();
        if self.history.is_some() {
            ends.extend(self.buf.cands.iter().map(|c| c.end));
            ends.sort_unstable();
        }
        for ci in 0..self.buf.cands.len() {
            let c = &self.buf.cands[ci];
            let (past, cue) = if self.is_history(c) {
                self.introduction(ci, &ends)
            } else {
                (None, None)
            };
            match (past, cue) {
                (Some(_), None) => quoted.push(c.start),
                (Some(p), Some(q)) => {
                    contested.get_or_insert((ci, p, q));
                    self.buf.live.push(ci);
                }
                _ => self.buf.live.push(ci),
            }
        }
        self.buf.ends = ends;
        // only quotations of the history: no other reading contradicts it (a stopped car predicted to stay stopped)
        if self.buf.live.is_empty() {
            quoted.clear();
            self.buf.live.extend(0..self.buf.cands.len());
        }
        // a correction or final-answer cue between candidates: the ones after the last such cue
        let mut cue = None;
        if self.buf.live.len() > 1 {
            for &(cpos, cend) in self.buf.cues.iter().rev() {
                let cands = &self.buf.cands;
                let live = &self.buf.live;
                if live.iter().any(|&c| cands[c].end <= cpos)
                    && live.iter().any(|&c| cands[c].start >= cend)
                {
                    self.buf.live.retain(|&c| cands[c].start >= cend);
                    cue = Some((cpos, cend));
                    break;
                }
            }
        }
        // a history-equal list introduced both as the past and as the answer, beside a different list
        if let Some((ci, (pp, pe), (qp, qe))) = contested {
            let other = self.buf.cands.iter().any(|c| !self.is_history(c));
            if self.buf.live.contains(&ci) && other {
                return Reading::Ambiguous(format!(
                    "ambiguous: the list at position {} equals the history given in the prompt and is \
                     introduced both as the past ({:?} at position {pp}) and as the answer ({:?} at \
                     position {qp}), beside a different list",
                    self.buf.cands[ci].start,
                    self.snippet(pp, pe),
                    self.snippet(qp, qe)
                ));
            }
        }
        // distinct readings among the rest
        let mut reps = [0_usize; 9];
        let mut distinct = 0;
        for &c in &self.buf.live {
            if !reps[..distinct].iter().any(|&r| self.same(r, c)) {
                reps[distinct] = c;
                distinct += 1;
                if distinct == reps.len() {
                    break;
                }
            }
        }
        let reps = &reps[..distinct];
        if reps.len() > 1 {
            let starts: Vec<usize> = reps.iter().map(|&r| self.buf.cands[r].start).collect();
            let many = if reps.len() > 8 { "more than 8" } else { "" };
            let count = if many.is_empty() {
                reps.len().to_string()
            } else {
                many.to_owned()
            };
            let after = match cue {
                Some((p, e)) => format!(" after the cue {:?} at position {p}", self.snippet(p, e)),
                None => String::new(),
            };
            return Reading::Ambiguous(format!(
                "ambiguous: {count} different lists of {n} actions{after} (at positions {}), \
                 and no correction or final-answer cue says which is the answer",
                positions(&starts)
            ));
        }
        let chosen_index = *self.buf.live.last().expect("live is not empty");
        let repeats = self.buf.live.len();
        let chosen = &self.buf.cands[chosen_index];
        if let Some((k, p)) = chosen.bad {
            let reason = self.bad_reason(k, &p);
            return if matches!(p.value, Err(BadPair::Range(..))) {
                Reading::Ambiguous(reason)
            } else {
                Reading::Failed(reason)
            };
        }
        if let Some(i) = chosen.stray {
            let t = self.tokens[i];
            return Reading::Failed(format!(
                "a number outside the pairs of the list: {:?} at position {}",
                self.snippet(t.pos, t.end),
                t.pos
            ));
        }
        let values = chosen.values;
        self.out
            .copy_from_slice(&self.buf.values[values..values + 2 * n]);
        let mut notes = Vec::new();
        if self.is_history(chosen) {
            let alone = self.buf.cands.iter().all(|c| self.is_history(c));
            notes.push(if alone {
                "the list equals the history given in the prompt (no other list)".to_owned()
            } else {
                "the list equals the history given in the prompt".to_owned()
            });
        }
        if !quoted.is_empty() {
            notes.push(format!(
                "skipped {} list(s) repeating the history given in the prompt (at position {})",
                quoted.len(),
                positions(&quoted)
            ));
        }
        if let Some((p, e)) = cue {
            notes.push(format!(
                "took the list after the cue {:?} at position {p}",
                self.snippet(p, e)
            ));
        }
        if repeats > 1 {
            notes.push(format!("the same list given {repeats} times"));
        }
        match chosen.shape {
            Shape::Pairs => {
                if !chosen.explicit {
                    notes.push("pairs without an enclosing list".to_owned());
                }
            }
            Shape::Spaced => notes.push("pairs written as 'v c' items".to_owned()),
            Shape::Flat => notes.push(format!(
                "a flat list of {} numbers read as v1, c1, v2, c2, …",
                2 * n
            )),
            Shape::Labelled => {
                notes.push("speeds and curvatures read from their labelled lists".to_owned())
            }
            Shape::Loose(how) => notes.push(format!("read {} standalone numbers {how}", 2 * n)),
        }
        let whole = (self.tokens[0].pos, self.tokens[self.tokens.len() - 1].end);
        if chosen.explicit && (chosen.start, chosen.end) != whole {
            notes.push("text around the list".to_owned());
        }
        let (e0, e1) = chosen.expr;
        if e1 > e0 {
            let which: Vec<String> = self.buf.expr[e0..e1].iter().map(usize::to_string).collect();
            notes.push(format!("expression evaluated (pair {})", which.join(", ")));
        }
        if chosen.keyed {
            notes.push("pairs read by their keys (speed, curvature)".to_owned());
        }
        if chosen.unicode {
            notes.push("unicode minus read as '-'".to_owned());
        }
        Reading::Found(notes)
    }

    /// The standalone numbers, paired by their layout: a candidate, or why not.
    fn loose(&mut self) -> Result<(), Reading> {
        let n = self.n;
        let text = self.text.as_bytes();
        let mut count = 0;
        let mut span = (0, 0);
        for (k, x) in self.buf.loose.iter().enumerate() {
            let Loose::Num(_, p, e) = *x else { continue };
            if count == 0 {
                span.0 = p;
            }
            span.1 = e;
            count += 1;
            // a range or a subtraction: `4.5-5.0`, `4.5 - 5.0` on one line
            if let [Loose::Minus(_), Loose::Num(_, p2, e2), ..] = self.buf.loose[k + 1..] {
                if !text[e..p2].contains(&b'\n') {
                    return Err(Reading::Ambiguous(format!(
                        "ambiguous: {:?} at position {p} is a range or a subtraction",
                        self.snippet(p, e2)
                    )));
                }
            }
        }
        if count != 2 * n {
            return Err(Reading::Failed(format!(
                "no bracketed pairs, and {count} standalone number(s) where exactly {} are needed",
                2 * n
            )));
        }
        let off = self.buf.values.len();
        self.buf.values.resize(off + 2 * n, f64::NAN);
        let how = if self.labelled(off) {
            "by their speed / curvature labels"
        } else if self.table(off) {
            "as the columns of a table"
        } else if self.per_line(off, false) {
            "one pair per line"
        } else {
            self.buf.values.truncate(off);
            return Err(Reading::Ambiguous(format!(
                "ambiguous: {count} standalone numbers, but their pairing is unknown (no speed / \
                 curvature labels, not one pair per line)"
            )));
        };
        self.offer_values(span, off, false, Shape::Loose(how));
        Ok(())
    }

    /// Every number after a speed or a curvature key, `n` of each: the k-th speed with the
    /// k-th curvature, written at `values[off..]`.
    fn labelled(&mut self, off: usize) -> bool {
        let n = self.n;
        let mut key: Option<bool> = None;
        let mut had_numbers = false;
        let (mut speeds, mut curvatures) = (0, 0);
        for x in &self.buf.loose {
            match *x {
                Loose::Key(k, _) => {
                    key = Some(k);
                    had_numbers = false;
                }
                Loose::Prose(_) if had_numbers => key = None,
                Loose::Num(v, ..) => {
                    had_numbers = true;
                    let (count, slot) = match key {
                        Some(true) => (&mut speeds, 0),
                        Some(false) => (&mut curvatures, 1),
                        None => return false,
                    };
                    if *count == n {
                        return false;
                    }
                    self.buf.values[off + 2 * *count + slot] = v;
                    *count += 1;
                }
                _ => {}
            }
        }
        speeds == n && curvatures == n
    }

    /// `n` lines (or `;` groups) of exactly two numbers each, written at `values[off..]`
    /// (swapped when `swap`).
    fn per_line(&mut self, off: usize, swap: bool) -> bool {
        let text = self.text.as_bytes();
        let mut lines = 0; // complete lines of two
        let mut current = 0; // numbers on the current line
        let mut last = 0;
        for x in &self.buf.loose {
            let pos = match *x {
                Loose::Num(_, p, _) | Loose::Key(_, p) | Loose::Prose(p) | Loose::Minus(p) => p,
                Loose::Break(p) => p,
            };
            let breaks = matches!(x, Loose::Break(_)) || text[last.min(pos)..pos].contains(&b'\n');
            if breaks && current > 0 {
                if current != 2 {
                    return false;
                }
                lines += 1;
                current = 0;
            }
            last = pos;
            if let Loose::Num(v, _, e) = *x {
                if current == 2 || lines == self.n {
                    return false;
                }
                let slot = if swap { 1 - current } else { current };
                self.buf.values[off + 2 * lines + slot] = v;
                current += 1;
                last = e;
            }
        }
        if current == 2 {
            lines += 1;
        } else if current > 0 {
            return false;
        }
        lines == self.n
    }

    /// A header line naming speed and curvature (no numbers before it, no other keys), then
    /// `n` rows of two numbers, written at `values[off..]` in the header's order.
    fn table(&mut self, off: usize) -> bool {
        let text = self.text.as_bytes();
        let mut keys: [(bool, usize); 2] = [(false, 0); 2];
        let mut found = 0;
        let mut before_numbers = true;
        for x in &self.buf.loose {
            match *x {
                Loose::Key(k, p) => {
                    if found == 2 || !before_numbers {
                        return false; // keys after the header make the layout something else
                    }
                    keys[found] = (k, p);
                    found += 1;
                }
                Loose::Num(..) => before_numbers = false,
                _ => {}
            }
        }
        let [(first, p1), (second, p2)] = keys;
        if found != 2 || first == second || text[p1..p2].contains(&b'\n') {
            return false;
        }
        self.per_line(off, !first)
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
                    BadNum::DoubledSign => format!("{num} has a doubled sign"),
                }
            }
            Err(BadPair::Range(pos, end)) => format!(
                "is ambiguous: {} is a range or a subtraction",
                self.snippet(pos, end)
            ),
            Err(BadPair::Count(c)) => format!("holds {c} value(s), not 2"),
            Err(BadPair::Symbols) => "is not two numbers".to_owned(),
            Err(BadPair::Expression) => "is not two numbers or simple expressions".to_owned(),
            Err(BadPair::Keys) => "has no single speed and curvature key".to_owned(),
            Ok(_) => "is fine".to_owned(),
        };
        format!("pair {} {group} {what}", k + 1)
    }
}

/// Byte positions, joined for a reason: `12`, `12 and 80`, `12, 80 and 140`.
fn positions(p: &[usize]) -> String {
    let s: Vec<String> = p.iter().map(usize::to_string).collect();
    match s.len() {
        0 => String::new(),
        1 => s[0].clone(),
        k => format!("{} and {}", s[..k - 1].join(", "), s[k - 1]),
    }
}

/// Whether the word `w` (followed by the token `next`) says that a corrected or final
/// answer follows: `Wait`, `Actually`, `Correction`, `Corrected`, `Revised`, `Updated`
/// (capitalised, or followed by punctuation: `wait,`), `Final answer`, `Final:` (any case).
fn is_cue(w: &str, next: Option<&Token>, text: &str) -> bool {
    const CUES: &[&str] = &[
        "wait",
        "actually",
        "correction",
        "corrections",
        "corrected",
        "revised",
        "revision",
        "updated",
    ];
    const FINAL_WHAT: &[&str] = &[
        "answer",
        "answers",
        "actions",
        "action",
        "list",
        "output",
        "plan",
        "prediction",
        "predictions",
        "result",
        "trajectory",
    ];
    if w.len() < 4
        || w.len() > 11
        || !matches!(
            w.as_bytes()[0] | 0x20,
            b'a' | b'c' | b'f' | b'r' | b'u' | b'w'
        )
    {
        return false;
    }
    let eq = |list: &[&str], s: &str| list.iter().any(|c| c.eq_ignore_ascii_case(s));
    if eq(CUES, w) {
        // a sentence's first word or followed by punctuation (`Wait,`, `Corrected:`, `actually:`):
        // "we could wait for the pedestrian" is no correction
        let punctuated = next.is_some_and(|t| match t.kind {
            Kind::Comma | Kind::Semicolon => true,
            Kind::Other => text[t.pos..].starts_with([':', '!', '.', '\u{2014}']),
            _ => false,
        });
        return w.as_bytes()[0].is_ascii_uppercase() || punctuated;
    }
    if !w.eq_ignore_ascii_case("final") {
        return false;
    }
    match next {
        Some(t) => match t.kind {
            Kind::Word { .. } => eq(FINAL_WHAT, &text[t.pos..t.end]),
            Kind::Other => text[t.pos..].starts_with(':'),
            _ => false,
        },
        None => false,
    }
}

/// Whether the word `w` says that a list after it is the past: `past`, `previous`,
/// `previously`, `history`, `histories`, `historical` (any case).
fn is_past(w: &str) -> bool {
    const PAST: &[&str] = &[
        "past",
        "previous",
        "previously",
        "history",
        "histories",
        "historical",
    ];
    w.len() >= 4
        && w.len() <= 10
        && matches!(w.as_bytes()[0] | 0x20, b'p' | b'h')
        && PAST.iter().any(|p| p.eq_ignore_ascii_case(w))
}

/// `Some(true)` for a word naming speeds (`speed`, `speeds`, `v`, `velocity`, …),
/// `Some(false)` for curvatures (`curvature`, `curvatures`, `c`, `k`, `κ`, `kappa`, …):
/// the label of a sequence or a table column. No allocation: most words are rejected by
/// their first byte.
fn sequence_key(word: &str) -> Option<bool> {
    let first = *word.as_bytes().first()? | 0x20;
    if word.len() > 12 || !(matches!(first, b'v' | b's' | b'c' | b'k') || word.starts_with('κ')) {
        return None;
    }
    if word.is_ascii() {
        let stem = word.trim_end_matches(|c: char| c.is_ascii_digit() || c == '_');
        let is = |names: &[&str]| names.iter().any(|n| n.eq_ignore_ascii_case(stem));
        if is(&[
            "v",
            "speed",
            "velocity",
            "vel",
            "speeds",
            "velocities",
            "vels",
        ]) {
            return Some(true);
        }
        if is(&[
            "c",
            "k",
            "kappa",
            "curvature",
            "curv",
            "curvatures",
            "curvs",
            "kappas",
        ]) {
            return Some(false);
        }
        return None;
    }
    key_kind(word)
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
            (Ok(a), Ok(b)) => {
                pair.expr = a.expr || b.expr;
                pair.unicode = a.unicode || b.unicode;
                Ok((a.value, b.value))
            }
            (Err(e), _) | (_, Err(e)) => Err(e),
        }
    };
    Leaf::Pair(pair)
}

struct Value {
    value: f64,
    expr: bool,
    unicode: bool,
}

/// One item of a pair: `[±] a [op b]`, or `a +b` (a signed number after a number).
/// `a - b`, `a-b` and `a -b` are a range or a subtraction: [`BadPair::Range`]; a sign
/// before a signed number (`- -0.01`, `5 + -1`) is a doubled sign.
fn expression(item: &[Token]) -> Result<Value, BadPair> {
    let (Some(first_tok), Some(last_tok)) = (item.first(), item.last()) else {
        return Err(BadPair::Expression);
    };
    let span = (first_tok.pos, last_tok.end);
    let doubled = BadPair::Number(BadNum::DoubledSign, span.0, span.1);
    let mut toks = item.iter().filter(|t| t.kind != Kind::Unit).map(|t| t.kind);
    let mut unicode = false;
    let mut first = toks.next().ok_or(BadPair::Expression)?;
    let mut negate = false;
    if let Kind::Op { op, plain } = first {
        if op != b'-' && op != b'+' {
            return Err(BadPair::Expression);
        }
        negate = op == b'-';
        unicode |= !plain;
        first = toks.next().ok_or(BadPair::Expression)?;
        if matches!(first, Kind::Num { signed: true, .. }) {
            return Err(doubled);
        }
    }
    let Kind::Num {
        value: a, plain, ..
    } = first
    else {
        return Err(BadPair::Expression);
    };
    unicode |= !plain;
    let a = if negate { -a } else { a };
    let value = match (toks.next(), toks.next(), toks.next()) {
        (None, _, _) => {
            return Ok(Value {
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
            if b.is_sign_negative() {
                return Err(BadPair::Range(span.0, span.1));
            }
            unicode |= !plain;
            a + b
        }
        (
            Some(Kind::Op { op, plain }),
            Some(Kind::Num {
                value: b,
                plain: pb,
                signed,
            }),
            None,
        ) => {
            unicode |= !(plain && pb);
            match op {
                b'-' => return Err(BadPair::Range(span.0, span.1)),
                b'+' if signed => return Err(doubled),
                b'+' => a + b,
                b'*' => a * b,
                _ => a / b,
            }
        }
        _ => return Err(BadPair::Expression),
    };
    Ok(Value {
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
