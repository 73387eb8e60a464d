//! The one parser of method options: `NAME:key=value:key=value`, as `lfr compare --methods`
//! takes them. A method declares its options as data (`OptionSpec`: key, kind with its range,
//! default, one line of help) in `crate::registry`; this module checks a spec against them and
//! gives every error in one format, "`SPEC`: what is wrong", naming the offending pair.

use std::fmt;

use crate::error::Error;

/// What values an option takes.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum OptionKind {
    /// A whole number in `min..=max`.
    Count { min: u32, max: u32 },
    /// A finite number above 0.
    Positive,
    /// One of these words.
    Choice(&'static [&'static str]),
    /// A finite number between `min` and `max`, each end included unless it is open.
    Interval { min: f32, min_open: bool, max: f32, max_open: bool },
}

/// One option of a method.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct OptionSpec {
    pub key: &'static str,
    pub kind: OptionKind,
    /// The value the method uses when the option is not given, as it would be written.
    pub default: &'static str,
    pub help: &'static str,
}

impl OptionSpec {
    /// What `--list-methods` shows for the values: `1..=1024`, `> 0`, `geometry|own-pixel`.
    pub fn range(&self) -> String {
        match self.kind {
            OptionKind::Count { min, max } => format!("{min}..={max}"),
            OptionKind::Positive => "> 0".to_string(),
            OptionKind::Choice(words) => words.join("|"),
            OptionKind::Interval { min, min_open, max, max_open } => {
                format!("{}{min}, {max}{}", if min_open { "(" } else { "[" }, if max_open { ")" } else { "]" })
            }
        }
    }

    /// Parses `value`; an error says what values the option takes (it is reported for `spec`, the
    /// `NAME:key=value` pair as given).
    fn parse_value(&self, spec: &str, value: &str) -> Result<OptionValue, Error> {
        let key = self.key;
        let bad = |message: String| Error::Option { spec: spec.to_string(), message };
        match self.kind {
            OptionKind::Count { min, max } => match value.parse::<u32>() {
                Ok(n) if (min..=max).contains(&n) => Ok(OptionValue::Count(n)),
                _ => Err(bad(format!("{key} must be a whole number at least {min} and at most {max}"))),
            },
            OptionKind::Positive => match value.parse::<f32>() {
                Ok(x) if x.is_finite() && x > 0.0 => Ok(OptionValue::Real(x)),
                _ => Err(bad(format!("{key} must be positive and finite"))),
            },
            OptionKind::Choice(words) => match words.iter().find(|w| **w == value) {
                Some(word) => Ok(OptionValue::Choice(word)),
                None => Err(bad(format!("{key} must be one of {}", words.join(", ")))),
            },
            OptionKind::Interval { min, min_open, max, max_open } => {
                let inside = |x: f32| {
                    x.is_finite()
                        && if min_open { x > min } else { x >= min }
                        && if max_open { x < max } else { x <= max }
                };
                match value.parse::<f32>() {
                    Ok(x) if inside(x) => Ok(OptionValue::Real(x)),
                    _ => Err(bad(format!("{key} must be a number in {}", self.range()))),
                }
            }
        }
    }
}

/// A parsed value.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum OptionValue {
    Count(u32),
    Real(f32),
    Choice(&'static str),
}

impl fmt::Display for OptionValue {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            OptionValue::Count(n) => write!(f, "{n}"),
            OptionValue::Real(x) => write!(f, "{x}"),
            OptionValue::Choice(word) => write!(f, "{word}"),
        }
    }
}

/// The options given for one method, in the order the method declares them.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Options {
    values: Vec<(&'static str, OptionValue)>,
}

impl Options {
    /// Parses `text` (`key=value` pairs separated by `:`, possibly empty) against `specs`, the
    /// options of the method `method`. `known_elsewhere(key)` tells whether another method
    /// takes `key`, so that the error can say it does not apply here rather than that it is
    /// unknown.
    pub fn parse(
        method: &str,
        text: &str,
        specs: &'static [OptionSpec],
        known_elsewhere: impl Fn(&str) -> bool,
    ) -> Result<Options, Error> {
        let mut values: Vec<(&'static OptionSpec, OptionValue)> = Vec::new();
        for pair in text.split(':').filter(|p| !p.is_empty()) {
            let spec_text = format!("{method}:{pair}");
            let bad = |message: String| Error::Option { spec: spec_text.clone(), message };
            let (key, value) = pair.split_once('=').ok_or_else(|| bad(format!("`{pair}` is not key=value")))?;
            let Some(spec) = specs.iter().find(|s| s.key == key) else {
                let takes = if specs.is_empty() {
                    format!("{method} takes no options")
                } else {
                    format!("{method} takes {}", specs.iter().map(|s| s.key).collect::<Vec<_>>().join(", "))
                };
                return Err(bad(if known_elsewhere(key) {
                    format!("{key} does not apply to {method}; {takes}")
                } else {
                    format!("unknown option `{key}`; {takes}")
                }));
            };
            if values.iter().any(|(s, _)| s.key == key) {
                return Err(bad(format!("{key} is given twice")));
            }
            values.push((spec, spec.parse_value(&spec_text, value)?));
        }
        let order = |key: &str| specs.iter().position(|s| s.key == key);
        values.sort_by_key(|(spec, _)| order(spec.key));
        Ok(Options { values: values.into_iter().map(|(spec, value)| (spec.key, value)).collect() })
    }

    /// The value of `key`, if given.
    pub fn get(&self, key: &str) -> Option<OptionValue> {
        self.values.iter().find(|(k, _)| *k == key).map(|(_, v)| *v)
    }

    /// The whole number `key`, if given.
    pub fn count(&self, key: &str) -> Option<u32> {
        match self.get(key)? {
            OptionValue::Count(n) => Some(n),
            _ => None,
        }
    }

    /// The number `key`, if given.
    pub fn real(&self, key: &str) -> Option<f32> {
        match self.get(key)? {
            OptionValue::Real(x) => Some(x),
            _ => None,
        }
    }

    /// The word `key`, if given.
    pub fn choice(&self, key: &str) -> Option<&'static str> {
        match self.get(key)? {
            OptionValue::Choice(word) => Some(word),
            _ => None,
        }
    }

    pub fn is_empty(&self) -> bool {
        self.values.is_empty()
    }

    /// The options in `parse`'s syntax, in the method's order: `radius=8:eps_normal=0.001`.
    pub fn canonical(&self) -> String {
        self.values.iter().map(|(key, value)| format!("{key}={value}")).collect::<Vec<_>>().join(":")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const SPECS: &[OptionSpec] = &[
        OptionSpec { key: "radius", kind: OptionKind::Count { min: 1, max: 64 }, default: "24", help: "" },
        OptionSpec { key: "eps", kind: OptionKind::Positive, default: "0.01", help: "" },
        OptionSpec {
            key: "lookup",
            kind: OptionKind::Choice(&["geometry", "own-pixel"]),
            default: "geometry",
            help: "",
        },
    ];

    fn parse(text: &str) -> Result<Options, Error> {
        Options::parse("m", text, SPECS, |key| key == "iterations")
    }

    #[test]
    fn values_parse_into_their_kinds_in_declared_order() {
        let options = parse("lookup=own-pixel:eps=0.5:radius=8").unwrap();
        assert_eq!(options.count("radius"), Some(8));
        assert_eq!(options.real("eps"), Some(0.5));
        assert_eq!(options.choice("lookup"), Some("own-pixel"));
        assert_eq!(options.canonical(), "radius=8:eps=0.5:lookup=own-pixel");
        assert_eq!(parse(&options.canonical()).unwrap(), options, "canonical text parses back");
        assert!(parse("").unwrap().is_empty());
        assert_eq!(parse("radius=8").unwrap().real("radius"), None, "a count is not a real");
    }

    #[test]
    fn every_error_names_the_pair_and_what_is_wrong() {
        for (text, needles) in [
            ("radius", &["`m:radius`", "key=value"][..]),
            ("radius=0", &["`m:radius=0`", "at least 1", "at most 64"]),
            ("radius=65", &["at most 64"]),
            ("radius=1.5", &["m:radius=1.5", "whole number"]),
            ("radius=-1", &["m:radius=-1"]),
            ("eps=0", &["positive"]),
            ("eps=nan", &["positive"]),
            ("eps=inf", &["positive"]),
            ("eps=1e39", &["positive"]),
            ("lookup=nearest", &["geometry, own-pixel"]),
            ("iterations=3", &["does not apply to m", "radius, eps, lookup"]),
            ("sigma=2", &["unknown option `sigma`"]),
            ("radius=2:radius=3", &["given twice"]),
        ] {
            let error = parse(text).err().unwrap_or_else(|| panic!("{text} must fail")).to_string();
            for needle in needles {
                assert!(error.contains(needle), "{text}: {error}");
            }
        }
        let none = Options::parse("box", "k=1", &[], |_| false).unwrap_err().to_string();
        assert!(none.contains("box takes no options"), "{none}");
    }

    #[test]
    fn an_interval_keeps_its_closed_ends_and_refuses_its_open_ones() {
        const HALF_OPEN: &[OptionSpec] = &[
            OptionSpec {
                key: "tolerance",
                kind: OptionKind::Interval { min: 0.0, min_open: false, max: 1.0, max_open: true },
                default: "0.001",
                help: "",
            },
            OptionSpec {
                key: "weight",
                kind: OptionKind::Interval { min: 0.0, min_open: true, max: 1.0, max_open: false },
                default: "1",
                help: "",
            },
        ];
        let parse = |text: &str| Options::parse("m", text, HALF_OPEN, |_| false);
        assert_eq!(HALF_OPEN[0].range(), "[0, 1)");
        assert_eq!(HALF_OPEN[1].range(), "(0, 1]");
        assert_eq!(parse("tolerance=0").unwrap().real("tolerance"), Some(0.0));
        assert_eq!(parse("weight=1").unwrap().real("weight"), Some(1.0));
        assert_eq!(parse("tolerance=0.5:weight=0.25").unwrap().canonical(), "tolerance=0.5:weight=0.25");
        for bad in ["tolerance=1", "tolerance=-0.1", "tolerance=nan", "weight=0", "weight=1.01", "weight=inf"] {
            let error = parse(bad).unwrap_err().to_string();
            assert!(error.contains(&format!("`m:{bad}`")) && error.contains("must be a number in"), "{bad}: {error}");
        }
    }
}
