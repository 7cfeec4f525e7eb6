//! Reading the object classes a model's stage-1 scene description mentions (rules
//! `objects@lightemma/1`, docs/definitions.md#described-objects).
//!
//! Per text and per class of [`CLASSES`]: whether the description **affirms** an object of the
//! class (`a pedestrian is crossing`), **negates** it (`no pedestrians`, `clear of cyclists`,
//! `pedestrians: none`), only **hedges** about it (`watch for any pedestrians`, `cyclists may
//! appear`), or does not name it; and the count where one is stated (`two parked cars`).
//!
//! Words, not substrings: a fixed noun lexicon ([`NOUNS`]) looked up per word, with the words that
//! make a noun name a place or a marking instead (`bus stop`, `bike lane`, `pedestrian
//! crossing`), and the ego vehicle (`the ego car`, `our car`) skipped. A negator (`no`, `not`,
//! `without`, …) negates the class nouns after it up to the end of its clause (sentence
//! punctuation, a contrast word, or a comma that opens a new clause), at most 8 words on; a
//! hedge earlier in the clause (`potential`, `any`, `watch`, `may`, …) or right after the noun
//! (`pedestrians may cross`) hedges it. A class both affirmed and negated in one text is affirmed
//! (the text claims one somewhere). Counts: the number word or digits among the three words before
//! an affirmed noun (`a`/`an`/`one` = 1 for a singular noun); a bare plural or a vague quantity
//! (`cars`, `several cars`) makes the class's count unknown; `the`/`this`/`that`/`these`/`those`
//! refer back and add nothing. The count of a class is the sum over its counted mentions.
//!
//! Empty, over 64 KiB, non-UTF-8, binary, truncated-reasoning, prompt-echoing and non-English texts
//! are `unknown` on every class with the reason. One pass, a lookup per word, no regular expressions.

use std::collections::HashMap;
use std::sync::OnceLock;

use rayon::prelude::*;

/// The version of these rules, recorded beside every result that uses them.
pub const RULES: &str = "objects@lightemma/1";
/// Texts longer than this (bytes) are not read.
pub const MAX_BYTES: usize = 65_536;
/// Batches at least this large are read on all cores.
const PARALLEL_MIN: usize = 2048;
/// How far (words) a negator reaches.
const NEGATION_REACH: usize = 8;

/// The classes, in code order (columns of the mention arrays).
pub const CLASSES: &[&str] = &[
    "pedestrian",
    "cyclist",
    "motorcycle",
    "car",
    "truck",
    "bus",
    "traffic_cone",
    "barrier",
    "traffic_light",
    "traffic_sign",
];
const N: usize = 10;

/// Mention codes.
pub const NOT_MENTIONED: u8 = 0;
pub const AFFIRMED: u8 = 1;
pub const NEGATED: u8 = 2;
pub const HEDGED: u8 = 3;
pub const UNKNOWN: u8 = 255;
/// The names of the mention codes 0..=3.
pub const MENTIONS: &[&str] = &["not_mentioned", "affirmed", "negated", "hedged"];

const PEDESTRIAN: usize = 0;
const CYCLIST: usize = 1;
const CAR: usize = 3;
const BUS: usize = 5;
const TRAFFIC_LIGHT: usize = 8;

/// (word, class, plural) — the noun lexicon.
pub const NOUNS: &[(&str, usize, bool)] = &[
    ("pedestrian", 0, false),
    ("pedestrians", 0, true),
    ("person", 0, false),
    ("persons", 0, true),
    ("people", 0, true),
    ("walker", 0, false),
    ("walkers", 0, true),
    ("jogger", 0, false),
    ("joggers", 0, true),
    ("child", 0, false),
    ("children", 0, true),
    ("kid", 0, false),
    ("kids", 0, true),
    ("man", 0, false),
    ("men", 0, true),
    ("woman", 0, false),
    ("women", 0, true),
    ("crowd", 0, true),
    ("worker", 0, false),
    ("workers", 0, true),
    ("cyclist", 1, false),
    ("cyclists", 1, true),
    ("bicyclist", 1, false),
    ("bicyclists", 1, true),
    ("bicycle", 1, false),
    ("bicycles", 1, true),
    ("bike", 1, false),
    ("bikes", 1, true),
    ("motorcycle", 2, false),
    ("motorcycles", 2, true),
    ("motorbike", 2, false),
    ("motorbikes", 2, true),
    ("motorcyclist", 2, false),
    ("motorcyclists", 2, true),
    ("scooter", 2, false),
    ("scooters", 2, true),
    ("moped", 2, false),
    ("mopeds", 2, true),
    ("car", 3, false),
    ("cars", 3, true),
    ("sedan", 3, false),
    ("sedans", 3, true),
    ("suv", 3, false),
    ("suvs", 3, true),
    ("hatchback", 3, false),
    ("hatchbacks", 3, true),
    ("van", 3, false),
    ("vans", 3, true),
    ("minivan", 3, false),
    ("minivans", 3, true),
    ("jeep", 3, false),
    ("jeeps", 3, true),
    ("taxi", 3, false),
    ("taxis", 3, true),
    ("truck", 4, false),
    ("trucks", 4, true),
    ("lorry", 4, false),
    ("lorries", 4, true),
    ("pickup", 4, false),
    ("pickups", 4, true),
    ("bus", 5, false),
    ("buses", 5, true),
    ("busses", 5, true),
    ("minibus", 5, false),
    ("minibuses", 5, true),
    ("cone", 6, false),
    ("cones", 6, true),
    ("pylon", 6, false),
    ("pylons", 6, true),
    ("barrier", 7, false),
    ("barriers", 7, true),
    ("barricade", 7, false),
    ("barricades", 7, true),
    ("stoplight", 8, false),
    ("stoplights", 8, true),
    ("sign", 9, false),
    ("signs", 9, true),
    ("signage", 9, true),
    ("signpost", 9, false),
    ("signposts", 9, true),
];

/// Words after a noun that make it name a place, a marking or a part, not the object.
fn place_after(class: usize, next: &str) -> bool {
    match class {
        PEDESTRIAN => matches!(
            next,
            "crossing"
                | "crossings"
                | "crosswalk"
                | "crosswalks"
                | "signal"
                | "signals"
                | "light"
                | "lights"
                | "bridge"
                | "zone"
                | "zones"
                | "island"
                | "walkway"
                | "path"
                | "paths"
                | "sign"
                | "signs"
                | "area"
                | "lane"
        ),
        CYCLIST => matches!(
            next,
            "lane" | "lanes" | "path" | "paths" | "rack" | "racks" | "symbol" | "sign" | "signs"
        ),
        CAR => matches!(next, "park" | "parks" | "wash"),
        BUS => matches!(
            next,
            "stop"
                | "stops"
                | "lane"
                | "lanes"
                | "station"
                | "stations"
                | "shelter"
                | "bay"
                | "only"
        ),
        _ => false,
    }
}

const NEGATORS: &[&str] = &[
    "no", "not", "without", "none", "nor", "neither", "zero", "never", "absence", "lack", "devoid",
];
/// Words after `no` that make a sign's name (`a no parking sign`), not a negation.
const SIGN_NAMES: &[&str] = &[
    "parking",
    "entry",
    "stopping",
    "turn",
    "turning",
    "left",
    "right",
    "u-turn",
    "overtaking",
    "standing",
];
const HEDGES: &[&str] = &[
    "potential",
    "potentially",
    "possible",
    "possibly",
    "may",
    "might",
    "could",
    "any",
    "watch",
    "beware",
    "caution",
    "cautious",
    "careful",
    "aware",
    "alert",
    "lookout",
    "if",
    "should",
    "would",
    "expect",
    "anticipate",
    "whether",
    "unclear",
    "perhaps",
    "maybe",
    "likely",
    "unlikely",
];
/// Words right after a noun that hedge it (`pedestrians may cross`).
const POST_HEDGES: &[&str] = &["may", "might", "could", "would"];
/// Words after `not`/`none` near a noun that negate it (`pedestrians are not visible`).
const ABSENT_AFTER: &[&str] = &[
    "visible", "present", "seen", "observed", "detected", "around", "there", "in",
];
const CONTRAST: &[&str] = &[
    "but", "however", "while", "whereas", "although", "though", "except", "yet", "only", "besides",
];
/// Words after a comma that open a new clause (the negation stops there).
const CLAUSE_OPENERS: &[&str] = &[
    "and", "but", "while", "with", "although", "though", "whereas", "there", "which", "who", "a",
    "an", "the", "one", "it", "they", "its", "their", "this", "these", "some", "several",
];
const EGO: &[&str] = &["ego", "our", "my", "own"];
const ANAPHORIC: &[&str] = &[
    "the", "this", "that", "these", "those", "its", "their", "same", "other",
];
const VAGUE: &[&str] = &[
    "several", "some", "many", "few", "multiple", "various", "numerous", "lots", "lot", "couple",
    "group", "dozens",
];
const NUMBERS: &[(&str, i32)] = &[
    ("a", 1),
    ("an", 1),
    ("one", 1),
    ("single", 1),
    ("two", 2),
    ("three", 3),
    ("four", 4),
    ("five", 5),
    ("six", 6),
    ("seven", 7),
    ("eight", 8),
    ("nine", 9),
    ("ten", 10),
    ("eleven", 11),
    ("twelve", 12),
    ("both", 2),
    ("pair", 2),
];
/// What the stage-1 prompt says; an answer containing it echoes the prompt.
const PROMPT_ECHO: &[&str] = &[
    "you are an expert labeller of autonomous-driving data",
    "describe the driving scene: the other vehicles",
    "do not infer or describe what the ego vehicle itself is doing",
];
/// Common English words; a text of 8 or more words with under 1 in 10 of these is not English.
const ENGLISH: &[&str] = &[
    "the", "a", "an", "and", "to", "of", "is", "are", "in", "on", "at", "with", "there", "vehicle",
    "road", "car", "lane", "ahead", "left", "right", "side", "street", "traffic", "it", "its",
    "for", "by", "be",
];

/// One text's reading.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Objects {
    /// Per class: a mention code ([`AFFIRMED`] …), or [`UNKNOWN`] for an unreadable text.
    pub mentions: [u8; N],
    /// Per class: the stated count of its affirmed mentions, or -1 when none is stated.
    pub counts: [i32; N],
    /// Why the text is unknown, or what was hedged ("" when nothing).
    pub reason: String,
}

impl Objects {
    fn unknown(reason: String) -> Self {
        Self {
            mentions: [UNKNOWN; N],
            counts: [-1; N],
            reason,
        }
    }
}

const F_ENGLISH: u32 = 1;
const F_CONTRAST: u32 = 1 << 1;
const F_NEGATOR: u32 = 1 << 2;
const F_HEDGE: u32 = 1 << 3;
const F_CLAUSE_OPENER: u32 = 1 << 4;
const F_EGO: u32 = 1 << 5;
const F_ANAPHORIC: u32 = 1 << 6;
const F_VAGUE: u32 = 1 << 7;
const F_POST_HEDGE: u32 = 1 << 8;
const F_ABSENT_AFTER: u32 = 1 << 9;
const F_SIGN_NAME: u32 = 1 << 10;

/// A word's entry in the lexicon: its list flags and, for a noun, (class, plural).
#[derive(Default, Clone, Copy)]
struct Entry {
    flags: u32,
    noun: Option<(usize, bool)>,
}

/// Every listed word → its entry: one hash lookup per word instead of a scan of each list.
fn lexicon() -> &'static HashMap<&'static str, Entry> {
    static LEXICON: OnceLock<HashMap<&'static str, Entry>> = OnceLock::new();
    LEXICON.get_or_init(|| {
        let mut map: HashMap<&'static str, Entry> = HashMap::new();
        let lists: [(u32, &[&'static str]); 11] = [
            (F_ENGLISH, ENGLISH),
            (F_CONTRAST, CONTRAST),
            (F_NEGATOR, NEGATORS),
            (F_HEDGE, HEDGES),
            (F_CLAUSE_OPENER, CLAUSE_OPENERS),
            (F_EGO, EGO),
            (F_ANAPHORIC, ANAPHORIC),
            (F_VAGUE, VAGUE),
            (F_POST_HEDGE, POST_HEDGES),
            (F_ABSENT_AFTER, ABSENT_AFTER),
            (F_SIGN_NAME, SIGN_NAMES),
        ];
        for (flag, words) in lists {
            for w in words {
                map.entry(w).or_default().flags |= flag;
            }
        }
        for &(w, c, p) in NOUNS {
            map.entry(w).or_default().noun = Some((c, p));
        }
        map
    })
}

/// Whether `w` is in the list marked by `flag`.
fn has(w: &str, flag: u32) -> bool {
    !w.is_empty() && lexicon().get(w).is_some_and(|e| e.flags & flag != 0)
}

fn class_of(word: &str) -> Option<(usize, bool)> {
    // a hyphenated word is read by its last part ("semi-truck", "police-car")
    let last = if word.contains('-') {
        word.rsplit('-').next().unwrap_or(word)
    } else {
        word
    };
    if last.is_empty() {
        return None;
    }
    lexicon().get(last).and_then(|e| e.noun)
}

/// A word, or a clause break (`,` is `Comma`, sentence punctuation `Stop`).
#[derive(Clone, Copy, PartialEq, Eq)]
enum Tok<'a> {
    Word(&'a str),
    Comma,
    /// `:` — ends a clause, but a list label's answer follows it (`Pedestrians: none`)
    Colon,
    Stop,
}

fn tokens(lower: &str) -> Vec<Tok<'_>> {
    let mut out = Vec::new();
    let mut start: Option<usize> = None;
    for (i, c) in lower.char_indices() {
        let word_char = c.is_alphanumeric() || c == '-' || c == '\'';
        if word_char {
            if start.is_none() {
                start = Some(i);
            }
            continue;
        }
        if let Some(s) = start.take() {
            push_word(&mut out, &lower[s..i]);
        }
        match c {
            ',' => out.push(Tok::Comma),
            ':' => out.push(Tok::Colon),
            '.' | '!' | '?' | ';' | '\n' | '(' | ')' => out.push(Tok::Stop),
            _ => {}
        }
    }
    if let Some(s) = start {
        push_word(&mut out, &lower[s..]);
    }
    out
}

fn push_word<'a>(out: &mut Vec<Tok<'a>>, w: &'a str) {
    let w = w.trim_matches(|c| c == '-' || c == '\'');
    let w = w.strip_suffix("'s").unwrap_or(w);
    if !w.is_empty() {
        out.push(Tok::Word(w));
    }
}

fn screen(text: &str) -> Result<String, String> {
    if text.len() > MAX_BYTES {
        return Err(format!(
            "text too long: {} bytes (limit {MAX_BYTES})",
            text.len()
        ));
    }
    if text.trim().is_empty() {
        return Err("empty text".to_owned());
    }
    if text.contains('\u{FFFD}') {
        return Err("text is not valid UTF-8 (replacement characters)".to_owned());
    }
    if text
        .chars()
        .any(|c| c.is_control() && !matches!(c, '\n' | '\r' | '\t'))
    {
        return Err("text holds control characters (binary data?)".to_owned());
    }
    let mut ranges = Vec::new();
    let blocks = crate::parse::lenient::answer_ranges(text, &mut ranges);
    if blocks.unclosed {
        return Err("text ends inside a reasoning block (truncated)".to_owned());
    }
    let mut answer = String::with_capacity(text.len());
    for &(a, b) in &ranges {
        answer.push_str(&text[a..b]);
        answer.push('\n');
    }
    let lower = answer.to_lowercase();
    if lower.trim().is_empty() {
        return Err("empty text (only a reasoning block)".to_owned());
    }
    if let Some(p) = PROMPT_ECHO.iter().find(|p| lower.contains(*p)) {
        return Err(format!("text echoes the prompt ('{p}')"));
    }
    Ok(lower)
}

/// Read one scene description.
pub fn read_objects(text: &str) -> Objects {
    let lower = match screen(text) {
        Ok(l) => l,
        Err(reason) => return Objects::unknown(reason),
    };
    let toks = tokens(&lower);
    let words: Vec<&str> = toks
        .iter()
        .filter_map(|t| if let Tok::Word(w) = t { Some(*w) } else { None })
        .collect();
    let english = words.iter().filter(|w| has(w, F_ENGLISH)).count();
    if words.len() >= 8 && english * 10 < words.len() {
        return Objects::unknown(format!(
            "not English: {english} of {} words are common English words",
            words.len()
        ));
    }
    if words.is_empty() {
        return Objects::unknown("no words".to_owned());
    }
    let mut affirmed = [false; N];
    let mut negated = [false; N];
    let mut hedged = [false; N];
    let mut counts = [0i32; N];
    let mut counted = [true; N];
    let mut any_count = [false; N];
    let mut hedged_quotes: Vec<String> = Vec::new();
    // clause state
    let mut negation_left = 0usize; // words the current negation still reaches
    let mut hedge_in_clause = false;
    for (k, tok) in toks.iter().enumerate() {
        let w = match *tok {
            Tok::Stop | Tok::Colon => {
                negation_left = 0;
                hedge_in_clause = false;
                continue;
            }
            Tok::Comma => {
                let next = match toks.get(k + 1) {
                    Some(Tok::Word(n)) => *n,
                    _ => "",
                };
                if has(next, F_CLAUSE_OPENER) {
                    negation_left = 0;
                    hedge_in_clause = false;
                }
                continue;
            }
            Tok::Word(w) => w,
        };
        let next = |d: usize| match toks.get(k + d) {
            Some(Tok::Word(n)) => *n,
            _ => "",
        };
        // the words after a list label's colon (`Pedestrians: none visible`)
        let after_colon = |d: usize| match (toks.get(k + 1), toks.get(k + 1 + d)) {
            (Some(Tok::Colon), Some(Tok::Word(n))) => *n,
            _ => "",
        };
        let prev = |d: usize| {
            if d > k {
                return "";
            }
            match toks[k - d] {
                Tok::Word(p) => p,
                _ => "",
            }
        };
        if has(w, F_CONTRAST) {
            negation_left = 0;
            hedge_in_clause = false;
            continue;
        }
        if has(w, F_NEGATOR) {
            let sign = w == "no" && has(next(1), F_SIGN_NAME);
            if !sign {
                negation_left = NEGATION_REACH;
            }
            continue;
        }
        if (w == "free" || w == "clear") && next(1) == "of" {
            negation_left = NEGATION_REACH;
            continue;
        }
        if has(w, F_HEDGE) {
            hedge_in_clause = true;
        }
        // the class of this word: a noun, or "traffic light(s)/signal(s)", "stop light(s)"
        let class = match class_of(w) {
            Some(c) => Some(c),
            None if matches!(w, "light" | "lights" | "signal" | "signals")
                && matches!(prev(1), "traffic" | "stop" | "pedestrian") =>
            {
                Some((TRAFFIC_LIGHT, w.ends_with('s')))
            }
            None if w == "light" && matches!(prev(1), "red" | "green" | "amber" | "yellow") => {
                Some((TRAFFIC_LIGHT, false))
            }
            None => None,
        };
        let Some((class, plural)) = class else {
            negation_left = negation_left.saturating_sub(1);
            continue;
        };
        // a place or marking (`bus stop`), the ego vehicle (`our car`), or a noun modifying the head noun after it
        // (`pickup truck`, `police car`: the head counts once)
        let modifier = class_of(next(1)).is_some();
        if place_after(class, next(1)) || has(prev(1), F_EGO) || modifier {
            negation_left = negation_left.saturating_sub(1);
            continue;
        }
        let post_negated = (next(1) == "none")
            || after_colon(1) == "none"
            || after_colon(1) == "no"
            || ((next(1) == "not" || next(2) == "not" || next(3) == "not")
                && (has(next(2), F_ABSENT_AFTER)
                    || has(next(3), F_ABSENT_AFTER)
                    || has(next(4), F_ABSENT_AFTER)))
            || matches!(next(1), "absent" | "nowhere")
            || matches!(next(2), "absent" | "nowhere");
        if negation_left > 0 || post_negated {
            negated[class] = true;
        } else if hedge_in_clause || has(next(1), F_POST_HEDGE) {
            hedged[class] = true;
            if hedged_quotes.len() < 3 {
                let from = k.saturating_sub(2);
                let quote: Vec<&str> = toks[from..=k]
                    .iter()
                    .filter_map(|t| if let Tok::Word(x) = t { Some(*x) } else { None })
                    .collect();
                hedged_quotes.push(quote.join(" "));
            }
        } else {
            affirmed[class] = true;
            // the count: a number among the three words before the noun
            let mut stated: Option<i32> = None;
            let mut refers_back = false;
            let mut vague = false;
            for d in 1..=3 {
                let p = prev(d);
                if p.is_empty() {
                    break;
                }
                if let Some(&(_, n)) = NUMBERS.iter().find(|(x, _)| *x == p) {
                    if n == 1 && plural && matches!(p, "a" | "an") {
                        // "a few cars", "a group of people": not one
                        vague = true;
                    } else {
                        stated = Some(n);
                    }
                    break;
                }
                if let Ok(n) = p.parse::<i32>() {
                    if (0..=1000).contains(&n) {
                        stated = Some(n);
                    }
                    break;
                }
                if has(p, F_ANAPHORIC) {
                    refers_back = true;
                    break;
                }
                if has(p, F_VAGUE) {
                    vague = true;
                    break;
                }
            }
            if let (Some(n), false) = (stated, vague) {
                counts[class] += n;
                any_count[class] = true;
            } else if vague || !refers_back {
                counted[class] = false;
            }
        }
        negation_left = negation_left.saturating_sub(1);
    }
    let mut out = Objects {
        mentions: [NOT_MENTIONED; N],
        counts: [-1; N],
        reason: String::new(),
    };
    for c in 0..N {
        out.mentions[c] = if affirmed[c] {
            AFFIRMED
        } else if negated[c] {
            NEGATED
        } else if hedged[c] {
            HEDGED
        } else {
            NOT_MENTIONED
        };
        if affirmed[c] && counted[c] && any_count[c] {
            out.counts[c] = counts[c];
        }
    }
    if !hedged_quotes.is_empty() {
        out.reason = format!(
            "hedged, not counted as mentions: {}",
            hedged_quotes
                .iter()
                .map(|q| format!("'{q}'"))
                .collect::<Vec<_>>()
                .join(", ")
        );
    }
    out
}

/// Read a batch; large batches on all cores. `lossy[i]` marks a text that was not valid UTF-8
/// before it reached Rust.
pub fn read_batch<T: AsRef<str> + Sync>(texts: &[T], lossy: &[bool]) -> Vec<Objects> {
    let one = |(i, t): (usize, &T)| {
        if lossy.get(i).copied().unwrap_or(false) {
            Objects::unknown("text is not valid UTF-8 (lone surrogates)".to_owned())
        } else {
            read_objects(t.as_ref())
        }
    };
    if texts.len() >= PARALLEL_MIN {
        texts.par_iter().enumerate().map(one).collect()
    } else {
        texts.iter().enumerate().map(one).collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn mention(text: &str, class: &str) -> (&'static str, i32) {
        let c = CLASSES.iter().position(|x| *x == class).unwrap();
        let o = read_objects(text);
        let m = o.mentions[c];
        (
            if m == UNKNOWN {
                "unknown"
            } else {
                MENTIONS[m as usize]
            },
            o.counts[c],
        )
    }

    #[test]
    fn affirmed_negated_hedged() {
        assert_eq!(
            mention("A pedestrian is crossing the road ahead.", "pedestrian"),
            ("affirmed", 1)
        );
        assert_eq!(
            mention(
                "There are no pedestrians or cyclists on the road.",
                "pedestrian"
            )
            .0,
            "negated"
        );
        assert_eq!(
            mention(
                "There are no pedestrians or cyclists on the road.",
                "cyclist"
            )
            .0,
            "negated"
        );
        assert_eq!(
            mention("Watch out for any pedestrians near the curb.", "pedestrian").0,
            "hedged"
        );
        assert_eq!(
            mention(
                "No pedestrians are visible, and two cars are parked on the right.",
                "car"
            ),
            ("affirmed", 2)
        );
        assert_eq!(
            mention("Pedestrians are not visible in the scene.", "pedestrian").0,
            "negated"
        );
        assert_eq!(
            mention("The road is clear of pedestrians.", "pedestrian").0,
            "negated"
        );
        assert_eq!(
            mention("A car ahead in the left lane.", "pedestrian").0,
            "not_mentioned"
        );
    }

    #[test]
    fn places_ego_and_signs_are_not_objects() {
        assert_eq!(
            mention("The road has a pedestrian crossing ahead.", "pedestrian").0,
            "not_mentioned"
        );
        assert_eq!(
            mention("A bus stop is on the right side of the street.", "bus").0,
            "not_mentioned"
        );
        assert_eq!(
            mention(
                "There is a bike lane on the right side of the road.",
                "cyclist"
            )
            .0,
            "not_mentioned"
        );
        assert_eq!(
            mention("The ego car is in the right lane of the road.", "car").0,
            "not_mentioned"
        );
        assert_eq!(
            mention("There is a no parking sign on the right.", "traffic_sign").0,
            "affirmed"
        );
        assert_eq!(
            mention("The traffic lights ahead are green.", "traffic_light").0,
            "affirmed"
        );
    }

    #[test]
    fn counts() {
        assert_eq!(
            mention("Two cars ahead and a car on the left.", "car"),
            ("affirmed", 3)
        );
        assert_eq!(
            mention("Several cars are parked on the right.", "car"),
            ("affirmed", -1)
        );
        assert_eq!(
            mention("A car is ahead. The car is braking.", "car"),
            ("affirmed", 1)
        );
    }

    #[test]
    fn bad_input_is_unknown() {
        for t in [
            "",
            "   ",
            "\u{FFFD}abc",
            "Der Fußgänger überquert die Straße vor dem Auto sehr langsam heute",
        ] {
            let o = read_objects(t);
            assert!(o.mentions.iter().all(|&m| m == UNKNOWN), "{t}");
            assert!(!o.reason.is_empty());
        }
        assert_eq!(read_objects(&"a ".repeat(40_000)).mentions[0], UNKNOWN);
        let echo = "You are an expert labeller of autonomous-driving data. A car.";
        assert_eq!(read_objects(echo).mentions[CAR], UNKNOWN);
    }

    #[test]
    fn lexicon_classes_are_known() {
        assert_eq!(CLASSES.len(), N);
        for (_, c, _) in NOUNS {
            assert!(*c < N);
        }
        let _ = (PEDESTRIAN, CYCLIST, BUS);
    }
}
