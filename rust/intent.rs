//! Reading the stated driving intent from a model's stage-2 text (rules `intent@lightemma/1`,
//! docs/parsing.md#intents, docs/definitions.md#explanation-audit).
//!
//! The stage-2 prompt asks for a recap of the past 3 s, then how the ego vehicle should drive over
//! the next 3 s. Only the **planned** part is read: clauses with a future or obligation marker
//! (`should`, `will`, `must`, `next`, …), imperative sentences (`Slow down and stop.`), and text under
//! a plan label (`Plan:`, `Next 3 seconds:`). Clauses with a past marker and no future marker, text
//! under a recap label (`Recent intent:`) and sentences with neither marker are the recap.
//!
//! In the planned part, cue phrases (a fixed lexicon, [`PATTERNS`]) give a longitudinal class and a
//! lateral class. A cue that is negated (`do not accelerate`), conditional or hedged (`if the light
//! turns green, proceed`, `be prepared to stop`, `slow down or stop`), or about another road user
//! (`the car ahead will turn left`) is not a statement of the plan. Then per axis: the firm cues
//! must agree (decelerate + stop is stop, start + accelerate is start, stop + stay stopped is stop;
//! anything else is a contradiction, `unknown`); without a firm cue the axis is `unknown` and the
//! reason says why. Nothing is guessed.
//!
//! One pass over the text and a hash lookup per word: linear time, no regular expressions.

use std::collections::HashMap;
use std::hash::{BuildHasherDefault, Hasher};
use std::sync::OnceLock;

use rayon::prelude::*;

/// The version of these rules, recorded beside every result that uses them.
pub const RULES: &str = "intent@lightemma/1";
/// Texts longer than this (bytes) are not read (`unknown`, "text too long").
pub const MAX_BYTES: usize = 65_536;
/// The code of `unknown` in the class arrays.
pub const UNKNOWN: u8 = 255;
/// A reason names at most this many ignored statements per axis ("… (and 7 more)").
const MAX_NAMED: usize = 3;
/// Batches at least this large are read on all cores.
const PARALLEL_MIN: usize = 2048;

/// Longitudinal classes, in code order.
pub const LONGITUDINAL: &[&str] = &[
    "accelerate",
    "keep_speed",
    "decelerate",
    "stop",
    "stay_stopped",
    "start",
];
/// Lateral classes, in code order.
pub const LATERAL: &[&str] = &[
    "follow_lane",
    "turn_left",
    "turn_right",
    "change_lane_left",
    "change_lane_right",
];

const ACCELERATE: u8 = 0;
const DECELERATE: u8 = 2;
const STOP: u8 = 3;
const STAY_STOPPED: u8 = 4;
const START: u8 = 5;

/// What one text states: class codes (index into [`LONGITUDINAL`] / [`LATERAL`], or [`UNKNOWN`]),
/// the sentence each came from ("" when unknown) and a reason ("" when both were read plainly).
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct Intent {
    pub longitudinal: u8,
    pub lateral: u8,
    pub longitudinal_sentence: String,
    pub lateral_sentence: String,
    pub reason: String,
}

impl Intent {
    fn unknown(reason: String) -> Self {
        Intent {
            longitudinal: UNKNOWN,
            lateral: UNKNOWN,
            reason,
            ..Default::default()
        }
    }
}

/// The lexicon. One pattern per line: `axis class: element element …`; an element is
/// `word/word/…` (one of these words), `~N` (up to N filler words, [`FILLERS`]) or `!word/word/…`
/// (the next word is none of these; consumes nothing). At each word the longest match wins and its
/// words are consumed; `skip` patterns consume words that are no cue (`bus stop`).
pub const PATTERNS: &str = "\
lon accelerate: accelerate/accelerates/accelerating/acceleration
lon accelerate: speed/speeds/speeding up
lon accelerate: increase/increases/increasing/raise/raises/raising/build/builds/building/pick/picks/picking/gain/gains/gaining ~3 speed/velocity/pace/momentum
lon decelerate: decelerate/decelerates/decelerating/deceleration
lon decelerate: slow/slows/slowing/slowed down
lon decelerate: slow/slows/slowing !traffic/moving/vehicle/vehicles/car/cars/lane/lanes/pace/speed/speeds/truck/trucks/zone/cyclist/pedestrian/pedestrians
lon decelerate: reduce/reduces/reducing/lower/lowers/lowering/decrease/decreases/decreasing/cut/cuts/cutting/shed/sheds/shedding ~3 speed/velocity/pace
lon decelerate: brake/brakes/braking !light/lights/lamp/lamps
lon decelerate: ease/eases/easing ~1 off
lon stop: come/comes/coming/bring/brings/bringing ~4 stop/halt/standstill
lon stop: stop/stops/stopping !sign/signs/line/lines/light/lights/bar/bars/sign's
lon stop: halt/halts/halting
lon stay_stopped: remain/remains/remaining/stay/stays/staying/keep/keeps/keeping ~2 stopped/stationary/halted/parked/standing/motionless/immobile
lon stay_stopped: remain/remains/remaining/stay/stays/staying ~3 standstill/rest
lon stay_stopped: remain/remains/remaining/stay/stays/staying still
lon stay_stopped: hold/holds/holding ~2 position
lon stay_stopped: stay/stays/staying put
lon stay_stopped: continue/continues/continuing/keep/keeps/keeping ~1 waiting
lon start: start/starts/starting/begin/begins/beginning/resume/resumes/resuming ~1 moving/driving/motion/move/drive/rolling/roll
lon start: pull/pulls/pulling away/off
lon start: move/moves/moving off
lon start: set/sets/setting off
lon start: get/gets/getting moving/going
lon start: start/starts/starting from ~2 standstill/stop/rest
lon keep_speed: maintain/maintains/maintaining/keep/keeps/keeping/hold/holds/holding/sustain/sustains/sustaining/retain/retains/retaining ~3 speed/velocity/pace/momentum
lon keep_speed: constant/steady/same/consistent/stable/unchanged/uniform/cruising speed/velocity/pace
lon keep_speed: cruise/cruises/cruising
lon keep_speed: maintain/maintains/maintaining/hold/holds/holding/keep/keeps/keeping ~2 # m s
lon keep_speed: continue/continues/continuing/proceed/proceeds/proceeding/drive/drives/driving/travel/travels/travelling/traveling ~1 at ~2 current/present/existing/same/steady/constant speed/velocity/pace
lon keep_speed: speed unchanged
lon keep_speed: no change ~2 speed/velocity
lon keep_speed: neither accelerating/accelerate nor decelerating/decelerate/braking/brake
lon keep_speed: without accelerating/accelerating or decelerating/braking
skip skip: bus/tram stop/stops
skip skip: turn/turns signal/signals/indicator/indicators/lane/lanes
lat turn_left: turn/turns/turning/veer/veers/veering/bear/bears/bearing/curve/curves/curving/steer/steers/steering/swerve/swerves/swerving/swing/swings ~3 left/leftward/leftwards !lane/lanes
lat turn_left: left/left-hand turn/turns/curve/curves/bend/bends
lat turn_left: left-turn/left-turning
lat turn_left: make/makes/making/take/takes/taking/execute/executes/executing/complete/completes/completing/perform/performs/performing/initiate/initiates/initiating ~2 left !lane/lanes
lat turn_right: turn/turns/turning/veer/veers/veering/bear/bears/bearing/curve/curves/curving/steer/steers/steering/swerve/swerves/swerving/swing/swings ~3 right/rightward/rightwards !lane/lanes
lat turn_right: right/right-hand turn/turns/curve/curves/bend/bends
lat turn_right: right-turn/right-turning
lat turn_right: make/makes/making/take/takes/taking/execute/executes/executing/complete/completes/completing/perform/performs/performing/initiate/initiates/initiating ~2 right !lane/lanes
lat change_lane_left: change/changes/changing/switch/switches/switching ~2 lane/lanes ~3 left/leftward
lat change_lane_left: change/changes/changing/switch/switches/switching/move/moves/moving/merge/merges/merging/shift/shifts/shifting/steer/steers/steering/pull/pulls/pulling/cut/cuts/cutting/go/goes/going/drift/drifts ~3 left/left-hand/leftmost ~3 lane/lanes
lat change_lane_left: left lane change/changes/shift
lat change_lane_left: lane/lanes change/changes/changing/shift ~3 left/leftward
lat change_lane_left: merge/merges/merging ~2 left/leftward
lat change_lane_right: change/changes/changing/switch/switches/switching ~2 lane/lanes ~3 right/rightward
lat change_lane_right: change/changes/changing/switch/switches/switching/move/moves/moving/merge/merges/merging/shift/shifts/shifting/steer/steers/steering/pull/pulls/pulling/cut/cuts/cutting/go/goes/going/drift/drifts ~3 right/right-hand/rightmost ~3 lane/lanes
lat change_lane_right: right lane change/changes/shift
lat change_lane_right: lane/lanes change/changes/changing/shift ~3 right/rightward
lat change_lane_right: merge/merges/merging ~2 right/rightward
lat follow_lane: follow/follows/following/keep/keeps/keeping/stay/stays/staying/remain/remains/remaining/maintain/maintains/maintaining/continue/continues/continuing/hold/holds/holding/track/tracks/tracking/cruise/cruises/cruising/drive/drives/driving/proceed/proceeds/proceeding ~4 lane/lanes/lane's
lat follow_lane: follow/follows/following ~3 road/roadway/path/route/street/curve/bend
lat follow_lane: go/goes/going/continue/continues/continuing/drive/drives/driving/proceed/proceeds/proceeding/head/heads/heading/move/moves/moving/travel/travels/travelling/traveling/keep/keeps/keeping/stay/stays/staying ~2 straight
lat follow_lane: straight ahead/on/line/path/course/trajectory/forward
lat follow_lane: lane-keeping/lane-following
lat follow_lane: lane keeping/following
lat follow_lane: without turning/turn/changing
lat follow_lane: no lane change/changes
";

/// Words a `~N` gap may skip: articles, possessives, prepositions, degree adverbs and the
/// adjectives that qualify a speed or a lane.
pub const FILLERS: &[&str] = &[
    "the",
    "a",
    "an",
    "to",
    "its",
    "their",
    "his",
    "her",
    "our",
    "my",
    "your",
    "slightly",
    "gently",
    "gradually",
    "smoothly",
    "sharply",
    "slowly",
    "carefully",
    "safely",
    "moderately",
    "significantly",
    "steadily",
    "softly",
    "bit",
    "little",
    "into",
    "onto",
    "towards",
    "toward",
    "further",
    "current",
    "present",
    "same",
    "steady",
    "constant",
    "safe",
    "low",
    "lower",
    "reduced",
    "moderate",
    "cruising",
    "existing",
    "normal",
    "this",
    "that",
    "at",
    "in",
    "on",
    "of",
    "ego",
    "vehicle",
    "vehicle's",
    "car",
    "car's",
    "for",
    "comfortable",
    "consistent",
    "stable",
    "own",
    "complete",
    "full",
    "hard",
    "firmly",
    "quickly",
    "immediately",
    "now",
    "up",
    "left",
    "right",
    "middle",
    "center",
    "centre",
    "rightmost",
    "leftmost",
    "designated",
    "travel",
    "driving",
    "reasonable",
    "appropriate",
    "cautious",
    "controlled",
    "brief",
    "short",
    "wide",
    "tight",
    "upcoming",
    "next",
    "first",
    "one",
    "lane",
    "within",
    "and",
    "speed",
    "adjacent",
    "neighbouring",
    "neighboring",
    "other",
    "free",
    "open",
    "empty",
    "clear",
    "faster",
    "slower",
    "outer",
    "inner",
    "same",
    "centered",
    "centred",
    "about",
    "around",
    "approximately",
    "roughly",
];

/// How many words before a cue (in its clause) a negator reaches.
const NEGATION_WINDOW: usize = 4;
/// Words that negate a cue when they occur in the [`NEGATION_WINDOW`] words before it.
const NEGATORS: &[&str] = &[
    "not",
    "no",
    "never",
    "don't",
    "dont",
    "doesn't",
    "shouldn't",
    "won't",
    "wouldn't",
    "cannot",
    "can't",
    "mustn't",
    "isn't",
    "aren't",
    "avoid",
    "avoids",
    "avoiding",
    "without",
    "nor",
    "neither",
    "zero",
    "instead",
    "rather",
    "refrain",
    "unnecessary",
    "needn't",
    "nothing",
];
/// Words or two-word phrases that make a clause conditional anywhere in it.
const CONDITIONAL: &[&str] = &[
    "if",
    "unless",
    "otherwise",
    "case",
    "event",
    "provided",
    "assuming",
    "soon as",
    "whenever",
    "else",
    "when",
    "once",
];
/// Label words that open a plan section (with a future marker, [`FUTURE`]).
const PLAN_LABELS: &[&str] = &[
    "intent",
    "intention",
    "action",
    "actions",
    "behavior",
    "behaviour",
    "prediction",
    "decision",
    "recommendation",
    "maneuver",
    "manoeuvre",
];
/// Conditional openers at the start of a sentence: then the whole sentence is conditional.
const OPENERS: &[&str] = &[
    "if",
    "unless",
    "once",
    "when",
    "whenever",
    "provided",
    "assuming",
    "after",
    "otherwise",
];
/// Hedges: a cue after one of these in its clause is not a firm statement of the plan
/// (`may slow down`, `be prepared to stop`; but `decelerate to prepare for a stop` is firm).
const HEDGES: &[&str] = &[
    "may",
    "might",
    "could",
    "possibly",
    "perhaps",
    "maybe",
    "potentially",
    "prepared",
    "prepare",
    "prepares",
    "preparing",
    "ready",
    "consider",
    "considering",
    "likely",
    "probably",
    "either",
    "optionally",
    "possible",
];
/// Hedges anywhere in a clause make all of it not firm (`slow down as needed`).
const CLAUSE_HEDGES: &[&str] = &["needed", "necessary", "depending", "required", "warranted"];
/// Auxiliaries and modals: an agent named before the first of these is the clause's subject.
const AUXILIARIES: &[&str] = &[
    "should", "will", "shall", "must", "is", "are", "was", "were", "may", "might", "can", "could",
    "would", "needs", "need", "has", "have", "had", "does", "do", "seems", "appears", "'ll",
];
/// Future, obligation or plan markers.
const FUTURE: &[&str] = &[
    "should",
    "will",
    "shall",
    "must",
    "need",
    "needs",
    "has to",
    "have to",
    "going to",
    "plan",
    "plans",
    "planned",
    "planning",
    "next",
    "upcoming",
    "coming",
    "recommend",
    "recommended",
    "advisable",
    "advise",
    "intend",
    "intends",
    "intended",
    "aim",
    "aims",
    "best",
    "ought",
    "let's",
    "let",
    "future",
    "would",
    "can",
    "i'll",
    "we'll",
    "it'll",
    "it'd",
    "going forward",
    "from now",
    "proposed",
    "propose",
    "suggest",
    "suggested",
    "expected",
    "want",
];
/// Past markers: a clause with one of these and no future marker is the recap.
const PAST: &[&str] = &[
    "was",
    "were",
    "had",
    "has",
    "have",
    "been",
    "previously",
    "recently",
    "recent",
    "past",
    "history",
    "historical",
    "earlier",
    "so far",
    "last",
    "did",
    "prior",
    "until now",
    "currently",
];
/// Words that start an imperative sentence (a plan without a future marker).
const IMPERATIVE: &[&str] = &[
    "accelerate",
    "decelerate",
    "slow",
    "stop",
    "maintain",
    "keep",
    "continue",
    "proceed",
    "turn",
    "change",
    "yield",
    "brake",
    "stay",
    "remain",
    "follow",
    "go",
    "drive",
    "merge",
    "hold",
    "reduce",
    "increase",
    "speed",
    "ease",
    "come",
    "start",
    "begin",
    "resume",
    "prepare",
    "wait",
    "move",
    "cruise",
    "steer",
    "bear",
    "veer",
    "pull",
    "creep",
    "gradually",
    "gently",
    "carefully",
    "slightly",
    "cautiously",
    "be",
    "switch",
    "shift",
    "make",
    "take",
    "navigate",
    "approach",
    "halt",
    "avoid",
    "do",
    "don't",
    "never",
    "apply",
    "lower",
    "gain",
    "pick",
    "straight",
    "smoothly",
    "safely",
    "then",
    "now",
    "next",
    "plan",
];
/// Words that start a subordinate clause about the circumstances (skipped).
const SUBORDINATE: &[&str] = &[
    "while", "whereas", "although", "though", "because", "since", "as", "given", "due", "whilst",
    "where", "which", "who",
];
/// Coordinating words that end a clause.
const COORDINATING: &[&str] = &["and", "but", "or", "then", "nor", "plus"];
/// Other road users and objects: a cue after one of these (in its clause) is about them.
const OTHERS: &[&str] = &[
    "cars",
    "truck",
    "trucks",
    "bus",
    "buses",
    "pedestrian",
    "pedestrians",
    "cyclist",
    "cyclists",
    "bicycle",
    "bicycles",
    "bike",
    "bikes",
    "motorcycle",
    "motorcycles",
    "motorcyclist",
    "traffic",
    "vehicles",
    "others",
    "van",
    "vans",
    "suv",
    "light",
    "lights",
    "signal",
    "officer",
    "driver",
    "drivers",
    "people",
    "person",
    "lead",
    "leading",
    "preceding",
    "oncoming",
    "road",
    "street",
    "lane",
    "someone",
    "they",
    "them",
];
/// After `car` or `vehicle`, these make it another road user (`the car ahead`).
const AGENT_PLACES: &[&str] = &["ahead", "behind", "beside", "nearby", "in"];
/// Before an agent word, these make it the ego vehicle (`our car`).
const EGO_WORDS: &[&str] = &["ego", "our", "my", "own", "ego's"];
/// What the stage-2 prompt says; an answer containing it echoes the prompt.
const PROMPT_ECHO: &[&str] = &[
    "describe the ego vehicle's recent intent",
    "you are driving the ego vehicle",
    "answer in one paragraph of plain text",
    "positive curvature means turning left",
];
/// The first words of [`PROMPT_ECHO`].
const ECHO_STARTS: &[&str] = &["describe", "you", "answer", "positive"];
/// Common English words; a long text with almost none is not English.
const ENGLISH: &[&str] = &[
    "the", "a", "an", "and", "to", "of", "is", "should", "will", "in", "it", "vehicle", "ego",
    "speed", "lane", "its", "at", "with", "for", "be", "on", "car", "road", "ahead", "as", "by",
];

/// A small, fast hash for short words (FxHash's multiply-rotate).
#[derive(Default)]
struct WordHasher(u64);

impl WordHasher {
    #[inline]
    fn add(&mut self, word: u64) {
        self.0 = (self.0.rotate_left(5) ^ word).wrapping_mul(0x517c_c1b7_2722_0a95);
    }
}

impl Hasher for WordHasher {
    fn write(&mut self, bytes: &[u8]) {
        let mut chunks = bytes.chunks_exact(8);
        for chunk in &mut chunks {
            let mut word = [0u8; 8];
            word.copy_from_slice(chunk);
            self.add(u64::from_le_bytes(word));
        }
        let rest = chunks.remainder();
        if !rest.is_empty() {
            let mut word = [0u8; 8];
            word[..rest.len()].copy_from_slice(rest);
            self.add(u64::from_le_bytes(word) ^ ((rest.len() as u64) << 59));
        }
    }
    fn finish(&self) -> u64 {
        self.0
    }
}

type WordMap<V> = HashMap<&'static str, V, BuildHasherDefault<WordHasher>>;

// What a word is, as bits: one lookup per word replaces scanning the word lists.
const F_FUTURE: u32 = 1;
const F_PAST: u32 = 1 << 1;
const F_CONDITIONAL: u32 = 1 << 2;
const F_HEDGE: u32 = 1 << 3;
const F_CLAUSE_HEDGE: u32 = 1 << 4;
const F_NEGATOR: u32 = 1 << 5;
const F_OTHER: u32 = 1 << 6;
const F_IMPERATIVE: u32 = 1 << 7;
const F_SUBORDINATE: u32 = 1 << 8;
const F_COORDINATING: u32 = 1 << 9;
const F_ENGLISH: u32 = 1 << 10;
const F_AUXILIARY: u32 = 1 << 11;
const F_FILLER: u32 = 1 << 12;
const F_EGO: u32 = 1 << 13;
const F_PLACE: u32 = 1 << 14;
const F_PAIR: u32 = 1 << 15;
const F_CLAUSE_OPENER: u32 = 1 << 16;
const F_OPENER: u32 = 1 << 17;
const F_PLAN_LABEL: u32 = 1 << 18;
const F_CUE: u32 = 1 << 19;

/// The word lists behind each bit (two-word entries are checked pairwise, see [`has_marker`]).
fn flag_lists() -> [(u32, &'static [&'static str]); 18] {
    [
        (F_FUTURE, FUTURE),
        (F_PAST, PAST),
        (F_CONDITIONAL, CONDITIONAL),
        (F_HEDGE, HEDGES),
        (F_CLAUSE_HEDGE, CLAUSE_HEDGES),
        (F_NEGATOR, NEGATORS),
        (F_OTHER, OTHERS),
        (F_IMPERATIVE, IMPERATIVE),
        (F_SUBORDINATE, SUBORDINATE),
        (F_COORDINATING, COORDINATING),
        (F_ENGLISH, ENGLISH),
        (F_AUXILIARY, AUXILIARIES),
        (F_FILLER, FILLERS),
        (F_EGO, EGO_WORDS),
        (F_PLACE, AGENT_PLACES),
        (F_CLAUSE_OPENER, CLAUSE_OPENERS),
        (F_OPENER, OPENERS),
        (F_PLAN_LABEL, PLAN_LABELS),
    ]
}

#[derive(Clone, Copy, PartialEq, Eq, Debug)]
enum Cue {
    Lon(u8),
    Lat(u8),
    Skip,
}

#[derive(Debug)]
enum Elem {
    Words(Vec<&'static str>),
    Gap(usize),
    Not(Vec<&'static str>),
}

struct Pattern {
    cue: Cue,
    elems: Vec<Elem>,
}

struct Lexicon {
    patterns: Vec<Pattern>,
    /// first word → patterns starting with it
    first: WordMap<Vec<usize>>,
    /// word → its bits (`F_…`)
    flags: WordMap<u32>,
    /// two-word markers: (bit, first word, second word)
    pairs: Vec<(u32, &'static str, &'static str)>,
}

fn class_code(names: &[&str], name: &str) -> u8 {
    names
        .iter()
        .position(|n| *n == name)
        .unwrap_or_else(|| panic!("unknown class {name} in the intent lexicon")) as u8
}

fn lexicon() -> &'static Lexicon {
    static LEXICON: OnceLock<Lexicon> = OnceLock::new();
    LEXICON.get_or_init(|| {
        let mut patterns = Vec::new();
        let mut first: WordMap<Vec<usize>> = WordMap::default();
        for line in PATTERNS.lines().filter(|l| !l.trim().is_empty()) {
            let (head, body) = line.split_once(':').expect("pattern line has a ':'");
            let (axis, class) = head.split_once(' ').expect("pattern head is 'axis class'");
            let cue = match axis {
                "lon" => Cue::Lon(class_code(LONGITUDINAL, class)),
                "lat" => Cue::Lat(class_code(LATERAL, class)),
                _ => Cue::Skip,
            };
            let elems: Vec<Elem> = body
                .split_whitespace()
                .map(|e| {
                    if let Some(n) = e.strip_prefix('~') {
                        Elem::Gap(n.parse().expect("gap is ~N"))
                    } else if let Some(w) = e.strip_prefix('!') {
                        Elem::Not(w.split('/').collect())
                    } else {
                        Elem::Words(e.split('/').collect())
                    }
                })
                .collect();
            let Some(Elem::Words(starts)) = elems.first() else {
                panic!("a pattern starts with words: {line}");
            };
            for w in starts {
                first.entry(w).or_default().push(patterns.len());
            }
            patterns.push(Pattern { cue, elems });
        }
        let mut flags: WordMap<u32> = WordMap::default();
        let mut pairs = Vec::new();
        for (bit, list) in flag_lists() {
            for entry in list {
                match entry.split_once(' ') {
                    None => *flags.entry(entry).or_default() |= bit,
                    Some((a, b)) => {
                        *flags.entry(a).or_default() |= F_PAIR;
                        pairs.push((bit, a, b));
                    }
                }
            }
        }
        for w in first.keys() {
            *flags.entry(w).or_default() |= F_CUE;
        }
        Lexicon {
            patterns,
            first,
            flags,
            pairs,
        }
    })
}

/// The bits of a word (0 for a word in no list).
fn flags_of(w: &str) -> u32 {
    lexicon().flags.get(w).copied().unwrap_or(0)
}

fn is_in(words: &[&str], w: &str) -> bool {
    words.contains(&w)
}

/// Match `elems` against `ws` from `i`; the end of the longest match.
fn match_at(elems: &[Elem], ws: &[&str], i: usize) -> Option<usize> {
    let Some((elem, rest)) = elems.split_first() else {
        return Some(i);
    };
    match elem {
        Elem::Words(alts) => {
            if i < ws.len() && is_in(alts, ws[i]) {
                match_at(rest, ws, i + 1)
            } else {
                None
            }
        }
        Elem::Not(alts) => {
            if i < ws.len() && is_in(alts, ws[i]) {
                None
            } else {
                match_at(rest, ws, i)
            }
        }
        Elem::Gap(n) => {
            let mut best = None;
            for k in 0..=*n {
                if k > 0 && (i + k > ws.len() || flags_of(ws[i + k - 1]) & F_FILLER == 0) {
                    break;
                }
                if let Some(end) = match_at(rest, ws, i + k) {
                    best = best.max(Some(end));
                }
            }
            best
        }
    }
}

/// The longest cue of one axis (or a `skip` pattern) starting at word `i`: (end, cue).
fn cue_at(ws: &[&str], flags: &[u32], i: usize, lateral: bool) -> Option<(usize, Cue)> {
    if flags[i] & F_CUE == 0 {
        return None;
    }
    let lex = lexicon();
    let candidates = lex.first.get(ws[i])?;
    let mut best: Option<(usize, Cue)> = None;
    for &p in candidates {
        let pattern = &lex.patterns[p];
        let axis_ok = match pattern.cue {
            Cue::Lon(_) => !lateral,
            Cue::Lat(_) => lateral,
            Cue::Skip => true,
        };
        if !axis_ok {
            continue;
        }
        if let Some(end) = match_at(&pattern.elems, ws, i) {
            if best.is_none_or(|(e, _)| end > e) {
                best = Some((end, pattern.cue));
            }
        }
    }
    best
}

/// Whether a clause (its words and their bits, OR-ed in `union`) holds a marker of `bit`: a word
/// with the bit, or one of the two-word markers of that bit.
fn has_marker(ws: &[&str], union: u32, bit: u32) -> bool {
    union & bit != 0
        || (union & F_PAIR != 0
            && lexicon().pairs.iter().any(|&(b, first, second)| {
                b == bit && ws.windows(2).any(|p| p[0] == first && p[1] == second)
            }))
}

/// One clause: its words and how it reads.
struct Clause {
    /// its words: `Layout::words[range.0..range.1]`
    range: (usize, usize),
    sentence: usize,
    conditional: bool,
    /// alternatives (`or`) or a clause-wide hedge (`as needed`)
    hedged: bool,
    subordinate: bool,
    future: bool,
    past: bool,
}

#[derive(Clone, Copy, PartialEq, Eq)]
enum Section {
    None,
    Plan,
    Recap,
}

/// A cue found in the planned part.
struct Found {
    cue: Cue,
    sentence: usize,
    /// its words (with the negator): `Layout::words[phrase.0..phrase.1]`
    phrase: (usize, usize),
    negated: bool,
    hedged: bool,
    other: bool,
}

/// Words of a lowercased text split into sentences and clauses; byte ranges of the sentences.
struct Layout<'t> {
    /// every word of the text (numbers as `#`) and its bits
    words: Vec<&'t str>,
    flags: Vec<u32>,
    clauses: Vec<Clause>,
    sentences: Vec<(usize, usize)>,
    /// sentence index → section label that governs it
    sections: Vec<Section>,
    /// sentence index → it starts with an imperative verb
    imperative: Vec<bool>,
    /// a phrase of the stage-2 prompt the text repeats
    echo: Option<&'static str>,
}

fn is_word_char(c: char) -> bool {
    c.is_alphanumeric() || c == '\''
}

/// Words that start a conditional clause; after one, the rest of the sentence is conditional.
const CLAUSE_OPENERS: &[&str] = &[
    "if",
    "unless",
    "once",
    "when",
    "whenever",
    "otherwise",
    "provided",
    "assuming",
];
/// After `as`, these make `as …` part of the clause (a hedge or an idiom), not a subordinate clause.
const AS_IDIOMS: &[&str] = &[
    "needed",
    "necessary",
    "required",
    "appropriate",
    "well",
    "soon",
    "usual",
    "normal",
    "before",
    "planned",
    "much",
    "possible",
    "long",
    "far",
];

/// The sentence's clauses (ranges into `out.words`), classified; appended to `out`.
fn flush_sentence(
    out: &mut Layout<'_>,
    clauses: &mut Vec<(usize, usize)>,
    range: (usize, usize),
    section: Section,
) {
    clauses.retain(|&(a, b)| a < b);
    if clauses.is_empty() {
        return;
    }
    let s = out.sentences.len();
    out.sentences.push(range);
    out.sections.push(section);
    let (a0, b0) = clauses[0];
    let first = out.words[a0];
    let second = if b0 > a0 + 1 {
        out.words[a0 + 1]
    } else {
        clauses.get(1).map_or("", |&(a, _)| out.words[a])
    };
    let first_flags = out.flags[a0];
    let opener = first_flags & F_OPENER != 0
        || (first == "in" && second == "case")
        || (first == "should" && is_in(&["the", "it", "a", "an", "there", "any"], second));
    out.imperative.push(first_flags & F_IMPERATIVE != 0);
    let mut rest_conditional = opener;
    let mut previous_or = false;
    for (k, (a, b)) in clauses.drain(..).enumerate() {
        let words = &out.words[a..b];
        let flags = &out.flags[a..b];
        let union = flags.iter().fold(0, |acc, f| acc | f);
        if k > 0 && flags[0] & F_CLAUSE_OPENER != 0 {
            rest_conditional = true;
        }
        let conditional = rest_conditional || has_marker(words, union, F_CONDITIONAL);
        let ends_or = words.last() == Some(&"or");
        let hedged =
            has_marker(words, union, F_CLAUSE_HEDGE) || previous_or || ends_or || words[0] == "or";
        // "while keeping its lane": a participle clause of the same subject, not a circumstance
        let participle = is_in(&["while", "whilst"], words[0])
            && words.get(1).is_some_and(|w| w.ends_with("ing"));
        previous_or = ends_or;
        let clause = Clause {
            subordinate: flags[0] & F_SUBORDINATE != 0 && !participle,
            future: has_marker(words, union, F_FUTURE) || (k == 0 && flags[0] & F_IMPERATIVE != 0),
            past: has_marker(words, union, F_PAST),
            range: (a, b),
            sentence: s,
            conditional,
            hedged,
        };
        out.clauses.push(clause);
    }
}

/// The next word after byte `j` of `lower`, if any.
fn next_word(lower: &str, j: usize) -> &str {
    let rest = lower[j..].trim_start();
    let end = rest.find(|c: char| !is_word_char(c)).unwrap_or(rest.len());
    &rest[..end]
}

fn layout(lower: &str) -> Layout<'_> {
    let bytes = lower.as_bytes();
    let n = bytes.len();
    let mut out = Layout {
        words: Vec::with_capacity(n / 5),
        flags: Vec::with_capacity(n / 5),
        clauses: Vec::new(),
        sentences: Vec::new(),
        sections: Vec::new(),
        imperative: Vec::new(),
        echo: None,
    };
    // the current clause is out.words[cw..]; the sentence's finished clauses are `clauses`
    let mut cw = 0usize;
    let mut clauses: Vec<(usize, usize)> = Vec::new();
    let mut sentence_start = 0usize;
    let mut clause_start = 0usize;
    let mut section = Section::None;
    let mut i = 0;
    macro_rules! end_clause {
        () => {{
            clauses.push((cw, out.words.len()));
            cw = out.words.len();
        }};
    }
    while i < n {
        let c = if bytes[i] < 0x80 {
            bytes[i] as char
        } else {
            lower[i..].chars().next().unwrap_or(' ')
        };
        let len = c.len_utf8();
        if c.is_alphabetic() {
            let mut j = i + len;
            while j < n {
                let b = bytes[j];
                if b.is_ascii_alphanumeric() || b == b'\'' {
                    j += 1;
                    continue;
                }
                let d = if b < 0x80 {
                    b as char
                } else {
                    lower[j..].chars().next().unwrap_or(' ')
                };
                if is_word_char(d) {
                    j += d.len_utf8();
                } else if d == '-' && lower[j + 1..].starts_with(|e: char| e.is_alphabetic()) {
                    j += 1;
                } else {
                    break;
                }
            }
            if out.echo.is_none() && is_in(ECHO_STARTS, &lower[i..j]) {
                out.echo = PROMPT_ECHO
                    .iter()
                    .find(|p| lower[i..].starts_with(*p))
                    .copied();
            }
            let mut w = &lower[i..j];
            while let Some(stripped) = w.strip_suffix('\'') {
                w = stripped;
            }
            let f = flags_of(w);
            let empty = out.words.len() == cw;
            if f & F_COORDINATING != 0 && empty && w != "or" {
                // a coordinating word opening a clause ("…, and stop") is no part of it
            } else if f & F_COORDINATING != 0 {
                // "or" ends the clause before it and starts the next: both are alternatives
                if w == "or" {
                    out.words.push(w);
                    out.flags.push(f);
                }
                end_clause!();
                clause_start = i;
                if w == "or" {
                    out.words.push(w);
                    out.flags.push(f);
                }
            } else if f & F_SUBORDINATE != 0
                && !empty
                && !(w == "as"
                    && (is_in(AS_IDIOMS, next_word(lower, j))
                        || out
                            .words
                            .last()
                            .is_some_and(|p| is_in(&["as", "soon", "such"], p))))
            {
                end_clause!();
                clause_start = i;
                out.words.push(w);
                out.flags.push(f);
            } else {
                out.words.push(w);
                out.flags.push(f);
            }
            i = j;
            continue;
        }
        if c.is_ascii_digit() {
            // a number: its decimal points and thousands commas are no boundaries; it is no cue word
            let mut j = i + 1;
            while j < n
                && (bytes[j].is_ascii_digit()
                    || ((bytes[j] == b'.' || bytes[j] == b',')
                        && j + 1 < n
                        && bytes[j + 1].is_ascii_digit()))
            {
                j += 1;
            }
            out.words.push("#");
            out.flags.push(0);
            i = j;
            continue;
        }
        match c {
            '.' | '!' | '?' | '\n' => {
                end_clause!();
                flush_sentence(&mut out, &mut clauses, (sentence_start, i), section);
                sentence_start = i + len;
                clause_start = i + len;
            }
            ':' if (1..=6).contains(&(out.words.len() - cw)) => {
                // a label ("Plan:", "Recent intent:") governs the text after it; what came before it
                // in the sentence is a sentence of its own
                let union = out.flags[cw..].iter().fold(0, |a, f| a | f);
                let label_past = has_marker(&out.words[cw..], union, F_PAST);
                let label_plan = has_marker(&out.words[cw..], union, F_FUTURE | F_PLAN_LABEL);
                cw = out.words.len(); // the label's words belong to no clause
                flush_sentence(
                    &mut out,
                    &mut clauses,
                    (sentence_start, clause_start),
                    section,
                );
                if label_past {
                    section = Section::Recap;
                } else if label_plan {
                    section = Section::Plan;
                }
                sentence_start = i + len;
                clause_start = i + len;
            }
            ',' | ';' | ':' | '(' | ')' | '\u{2014}' | '\u{2013}' | '"' | '\u{201C}'
            | '\u{201D}' => {
                end_clause!();
                clause_start = i + len;
            }
            '-' if bytes.get(i + 1) == Some(&b' ') => {
                end_clause!();
                clause_start = i + len;
            }
            _ => {}
        }
        i += len;
    }
    end_clause!();
    flush_sentence(&mut out, &mut clauses, (sentence_start, n), section);
    let _ = cw;
    out
}

fn quote(words: &[&str], (a, b): (usize, usize)) -> String {
    words[a..b].join(" ")
}

/// The class of one axis from its cues, or why there is none.
fn resolve(
    words: &[&str],
    found: &[&Found],
    recap: usize,
    axis: &str,
    names: &[&str],
    lon: bool,
) -> (u8, Option<usize>, String) {
    let firm: Vec<&&Found> = found
        .iter()
        .filter(|f| !f.negated && !f.hedged && !f.other)
        .collect();
    let code = |f: &Found| match f.cue {
        Cue::Lon(c) | Cue::Lat(c) => c,
        Cue::Skip => UNKNOWN,
    };
    let ignored_count = found
        .iter()
        .filter(|f| f.negated || f.hedged || f.other)
        .count();
    let more = if ignored_count > MAX_NAMED {
        format!(" (and {} more)", ignored_count - MAX_NAMED)
    } else {
        String::new()
    };
    let ignored: Vec<String> = found
        .iter()
        .filter(|f| f.negated || f.hedged || f.other)
        .take(MAX_NAMED)
        .map(|f| {
            let why = if f.negated {
                "negated"
            } else if f.hedged {
                "conditional or hedged"
            } else {
                "about another road user"
            };
            format!("{why} '{}'", quote(words, f.phrase))
        })
        .collect();
    if firm.is_empty() {
        let reason = if !ignored.is_empty() {
            format!("{axis}: only {}{more}", ignored.join(", "))
        } else if recap > 0 {
            format!("{axis}: stated only in the recap of the past")
        } else {
            format!("{axis}: no {axis} intent stated in the planned part")
        };
        return (UNKNOWN, None, reason);
    }
    let mut classes: Vec<u8> = firm.iter().map(|f| code(f)).collect();
    classes.sort_unstable();
    classes.dedup();
    let merged = if classes.len() == 1 {
        Some(classes[0])
    } else if lon && (classes == [DECELERATE, STOP] || classes == [STOP, STAY_STOPPED]) {
        Some(STOP)
    } else if lon && classes == [ACCELERATE, START] {
        Some(START)
    } else {
        None
    };
    match merged {
        Some(c) => {
            let f = firm
                .iter()
                .find(|f| code(f) == c)
                .expect("a cue of the class");
            let reason = if ignored.is_empty() {
                String::new()
            } else {
                format!("{axis}: ignored {}{more}", ignored.join(", "))
            };
            (c, Some(f.sentence), reason)
        }
        None => {
            let a = firm[0];
            let b = firm
                .iter()
                .find(|f| code(f) != code(a))
                .expect("two classes");
            (
                UNKNOWN,
                None,
                format!(
                    "{axis}: contradictory statements '{}' ({}) and '{}' ({})",
                    quote(words, a.phrase),
                    names[code(a) as usize],
                    quote(words, b.phrase),
                    names[code(b) as usize]
                ),
            )
        }
    }
}

/// Read one stage-2 text under `intent@lightemma/1`.
pub fn read_intent(text: &str) -> Intent {
    if text.len() > MAX_BYTES {
        return Intent::unknown(format!(
            "text too long: {} bytes (limit {MAX_BYTES})",
            text.len()
        ));
    }
    if text.trim_ascii().is_empty() && text.trim().is_empty() {
        return Intent::unknown("empty text".to_owned());
    }
    // one pass: control characters, replacement characters, ASCII and other letters
    let (mut ascii, mut other, mut control, mut replacement) = (0usize, 0usize, false, false);
    let tb = text.as_bytes();
    let mut k = 0;
    while k < tb.len() {
        let b = tb[k];
        if b < 0x80 {
            ascii += usize::from(b.is_ascii_alphabetic());
            control |= b.is_ascii_control() && !matches!(b, b'\n' | b'\r' | b'\t');
            k += 1;
            continue;
        }
        let c = text[k..].chars().next().unwrap_or(' ');
        k += c.len_utf8();
        if c == '\u{FFFD}' {
            replacement = true;
        } else if c.is_alphabetic() {
            other += 1;
        } else {
            control |= c.is_control();
        }
    }
    if replacement {
        return Intent::unknown("text is not valid UTF-8 (replacement characters)".to_owned());
    }
    if control {
        return Intent::unknown("text holds control characters (binary data?)".to_owned());
    }
    // reasoning blocks are not the answer: blank them (same byte length, so offsets hold)
    let mut ranges = Vec::new();
    let blocks = crate::parse::lenient::answer_ranges(text, &mut ranges);
    if blocks.unclosed {
        return Intent::unknown("text ends inside a reasoning block (truncated)".to_owned());
    }
    // a removed block is a sentence break: a line break, then spaces (byte offsets hold)
    let blank = |norm: &mut String, len: usize| {
        if len > 0 {
            norm.push('\n');
            norm.extend(std::iter::repeat_n(' ', len - 1));
        }
    };
    let mut norm = String::with_capacity(text.len());
    let mut at = 0;
    for &(a, b) in &ranges {
        blank(&mut norm, a - at);
        norm.push_str(&text[a..b]);
        at = b;
    }
    blank(&mut norm, text.len() - at);
    if blocks.removed > 0 {
        // the language is that of the answer, not of its reasoning
        ascii = norm.bytes().filter(u8::is_ascii_alphabetic).count();
        other = norm
            .chars()
            .filter(|c| !c.is_ascii() && c.is_alphabetic())
            .count();
    }
    if norm.contains(['\u{2019}', '\u{2018}']) {
        norm = norm.replace(['\u{2019}', '\u{2018}'], "'");
    }
    let lower = norm.to_ascii_lowercase();
    if ascii + other == 0 {
        return Intent::unknown("text has no words".to_owned());
    }
    if other * 5 > ascii + other {
        return Intent::unknown(format!(
            "text is not English: {}% of its letters are not ASCII",
            100 * other / (ascii + other)
        ));
    }
    let lay = layout(&lower);
    if let Some(echo) = lay.echo {
        return Intent::unknown(format!("text echoes the stage-2 prompt (\"{echo}\")"));
    }
    let total_words = lay.words.iter().filter(|w| **w != "#").count();
    let english = lay.flags.iter().filter(|&&f| f & F_ENGLISH != 0).count();
    if total_words >= 8 && english * 10 < total_words {
        return Intent::unknown(format!(
            "text is not English: {english} of its {total_words} words are common English words"
        ));
    }
    // which clauses are the plan: a sentence is planned when it is imperative or one of its main
    // clauses has a future marker
    let mut sentence_future = vec![false; lay.sentences.len()];
    for clause in &lay.clauses {
        sentence_future[clause.sentence] |= clause.future && !clause.subordinate;
    }
    let mut found: Vec<Found> = Vec::new();
    let mut recap_cues = [0usize; 2];
    for (c, clause) in lay.clauses.iter().enumerate() {
        let s = clause.sentence;
        let recap_clause = clause.past && !clause.future;
        // a conditional is about the future by nature: its cues are read (and then set aside as
        // conditional), not counted as the recap
        let planned = !recap_clause
            && !clause.subordinate
            && (clause.conditional
                || match lay.sections[s] {
                    Section::Plan => true,
                    // a recap section ends at the first sentence with a future marker
                    Section::Recap => sentence_future[s] && !lay.imperative[s],
                    Section::None => sentence_future[s] || lay.imperative[s],
                });
        let ws = &lay.words[clause.range.0..clause.range.1];
        let fl = &lay.flags[clause.range.0..clause.range.1];
        // the clause's subject ends at its first auxiliary; an imperative clause's subject is the ego
        let first_of_imperative = lay.imperative[s] && (c == 0 || lay.clauses[c - 1].sentence != s);
        let subject_end = if first_of_imperative || fl[0] & F_IMPERATIVE != 0 {
            0
        } else {
            fl.iter()
                .position(|f| f & F_AUXILIARY != 0)
                .unwrap_or(ws.len())
        };
        // the first other road user named in the clause, and the first hedge (linear, once per clause)
        let other_at = (0..ws.len())
            .position(|k| {
                (fl[k] & F_OTHER != 0
                    || (is_in(&["car", "vehicle"], ws[k])
                        && fl.get(k + 1).is_some_and(|f| f & F_PLACE != 0)))
                    && !(k > 0 && fl[k - 1] & F_EGO != 0)
            })
            .unwrap_or(usize::MAX);
        let hedge_at = fl
            .iter()
            .position(|f| f & F_HEDGE != 0)
            .unwrap_or(usize::MAX);
        for lateral in [false, true] {
            let mut i = 0;
            while i < ws.len() {
                let Some((end, cue)) = cue_at(ws, fl, i, lateral) else {
                    i += 1;
                    continue;
                };
                if cue == Cue::Skip {
                    i = end;
                    continue;
                }
                if !planned {
                    recap_cues[usize::from(lateral)] += 1;
                    i = end;
                    continue;
                }
                let window = i.saturating_sub(NEGATION_WINDOW);
                let negator = fl[window..i].iter().position(|f| f & F_NEGATOR != 0);
                let negated = negator.is_some();
                let other = other_at < subject_end.min(i);
                let from = negator.map_or(i, |k| window + k);
                found.push(Found {
                    cue,
                    sentence: s,
                    phrase: (clause.range.0 + from, clause.range.0 + end),
                    negated,
                    hedged: clause.conditional || clause.hedged || hedge_at < i,
                    other,
                });
                i = end;
            }
        }
    }
    let lon: Vec<&Found> = found
        .iter()
        .filter(|f| matches!(f.cue, Cue::Lon(_)))
        .collect();
    let lat: Vec<&Found> = found
        .iter()
        .filter(|f| matches!(f.cue, Cue::Lat(_)))
        .collect();
    let (lon_code, lon_s, lon_reason) = resolve(
        &lay.words,
        &lon,
        recap_cues[0],
        "longitudinal",
        LONGITUDINAL,
        true,
    );
    let (lat_code, lat_s, lat_reason) =
        resolve(&lay.words, &lat, recap_cues[1], "lateral", LATERAL, false);
    let sentence = |s: Option<usize>| {
        s.map(|s| {
            let (a, b) = lay.sentences[s];
            norm[a..b].trim().to_owned()
        })
        .unwrap_or_default()
    };
    let reason = [lon_reason, lat_reason]
        .into_iter()
        .filter(|r| !r.is_empty())
        .collect::<Vec<_>>()
        .join("; ");
    Intent {
        longitudinal: lon_code,
        lateral: lat_code,
        longitudinal_sentence: sentence(lon_s),
        lateral_sentence: sentence(lat_s),
        reason,
    }
}

/// Read a batch; large batches on all cores. `lossy[i]` marks a text that was not valid UTF-8
/// before it reached Rust (its result is `unknown` with that reason).
pub fn read_batch<T: AsRef<str> + Sync>(texts: &[T], lossy: &[bool]) -> Vec<Intent> {
    let one = |(i, t): (usize, &T)| {
        if lossy.get(i).copied().unwrap_or(false) {
            Intent::unknown("text is not valid UTF-8 (lone surrogates)".to_owned())
        } else {
            read_intent(t.as_ref())
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

    fn names(text: &str) -> (&'static str, &'static str, String) {
        let i = read_intent(text);
        let name = |names: &'static [&'static str], c: u8| {
            if c == UNKNOWN {
                "unknown"
            } else {
                names[c as usize]
            }
        };
        (
            name(LONGITUDINAL, i.longitudinal),
            name(LATERAL, i.lateral),
            i.reason,
        )
    }

    #[test]
    fn plan_after_recap() {
        let (lon, lat, reason) = names(
            "The ego vehicle has been accelerating and turning left. It should now slow down and keep its lane.",
        );
        assert_eq!((lon, lat), ("decelerate", "follow_lane"), "{reason}");
        let i = read_intent("The ego vehicle has been accelerating. It should now slow down.");
        assert_eq!(i.longitudinal_sentence, "It should now slow down");
    }

    #[test]
    fn recap_only_is_unknown() {
        let (lon, lat, reason) =
            names("The ego vehicle was decelerating while following its lane.");
        assert_eq!((lon, lat), ("unknown", "unknown"));
        assert!(reason.contains("recap"), "{reason}");
    }

    #[test]
    fn negation_conditionals_and_contradictions() {
        let (lon, _, reason) = names("The ego vehicle should not accelerate.");
        assert_eq!(lon, "unknown");
        assert!(reason.contains("negated 'not accelerate'"), "{reason}");
        let (lon, lat, reason) =
            names("If the light turns green, proceed straight and accelerate.");
        assert_eq!((lon, lat), ("unknown", "unknown"));
        assert!(reason.contains("conditional"), "{reason}");
        let (lon, _, reason) = names("Accelerate now. Then decelerate.");
        assert_eq!(lon, "unknown");
        assert!(reason.contains("contradictory"), "{reason}");
        assert_eq!(names("Slow down and come to a stop.").0, "stop");
    }

    #[test]
    fn longest_match_and_skips() {
        assert_eq!(names("Merge into the left lane.").1, "change_lane_left");
        assert_eq!(names("Turn left.").1, "turn_left");
        assert_eq!(names("Approach the stop sign.").0, "unknown");
        assert_eq!(names("Remain at a standstill.").0, "stay_stopped");
    }

    #[test]
    fn bad_input_is_unknown_with_a_reason() {
        assert_eq!(read_intent("").reason, "empty text");
        let huge = "Slow down. ".repeat(MAX_BYTES / 8);
        assert!(read_intent(&huge).reason.starts_with("text too long"));
        assert!(read_intent("Stop \u{FFFD} now.").reason.contains("UTF-8"));
        assert!(read_intent("停车并保持车道").reason.contains("not English"));
        let r = read_batch(&["Stop.", "Stop."], &[false, true]);
        assert_eq!(r[0].longitudinal, 3);
        assert_eq!(r[1].longitudinal, UNKNOWN);
    }

    #[test]
    fn lexicon_classes_are_known() {
        // building the lexicon panics on a class name that is not one of the classes
        assert!(lexicon().patterns.len() > 40);
        for phrase in PROMPT_ECHO {
            let first = phrase.split(' ').next().unwrap_or("");
            assert!(ECHO_STARTS.contains(&first), "{phrase}");
            assert!(read_intent(&format!("Sure. {phrase}. Stop."))
                .reason
                .contains("echoes"));
        }
    }
}
