//! The `key=v,v,v,key=v` syntax shared by `--sun`, `--point`, `--camera`, `--medium` and the
//! `nimbus:` metadata strings.
//!
//! Tokens are split on commas; a token holding `=` starts a new key and every following token
//! without one is a further value of that key, so `dir=0,0,-1,irradiance=3` reads as
//! `dir: [0, 0, -1]`, `irradiance: [3]`. Numbers are Rust's `f32`/`f64` syntax (so `1e-3` and
//! the shortest round-trip text that `Display` writes). Keys are case-sensitive; `-` and `_`
//! are interchangeable in them (`look-at` = `look_at`).

use glam::{DVec3, Vec3};

/// A string in the `key=value,...` syntax that could not be read.
///
/// Displays as `invalid light 'dir=1,2' (dir needs 3 numbers, got 2)`, ready for the tools'
/// `error: <what> (<where>)` line.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("invalid {what} '{input}' ({reason})")]
pub struct ParseError {
    /// What was being parsed: "light", "camera", "medium".
    pub what: &'static str,
    /// The text as given.
    pub input: String,
    /// Why it was refused, naming the key at fault.
    pub reason: String,
}

pub(crate) struct KeyValues<'a> {
    what: &'static str,
    input: &'a str,
    entries: Vec<(String, Vec<&'a str>)>,
}

impl<'a> KeyValues<'a> {
    pub(crate) fn parse(what: &'static str, input: &'a str) -> Result<Self, ParseError> {
        let mut kv = KeyValues { what, input, entries: Vec::new() };
        if input.trim().is_empty() {
            return Err(kv.error("empty"));
        }
        for token in input.split(',') {
            let token = token.trim();
            if token.is_empty() {
                return Err(kv.error("empty value between commas"));
            }
            match token.split_once('=') {
                Some((key, value)) => {
                    let key = key.trim().replace('_', "-");
                    if key.is_empty() {
                        return Err(kv.error(format!("'{token}' has no key")));
                    }
                    if kv.entries.iter().any(|(k, _)| *k == key) {
                        return Err(kv.error(format!("{key} given twice")));
                    }
                    let value = value.trim();
                    if value.is_empty() {
                        return Err(kv.error(format!("{key} has no value")));
                    }
                    kv.entries.push((key, vec![value]));
                }
                None => match kv.entries.last_mut() {
                    Some((_, values)) => values.push(token),
                    None => return Err(kv.error(format!("'{token}' is not of the form key=value"))),
                },
            }
        }
        Ok(kv)
    }

    pub(crate) fn error(&self, reason: impl Into<String>) -> ParseError {
        ParseError { what: self.what, input: self.input.to_string(), reason: reason.into() }
    }

    pub(crate) fn has(&self, key: &str) -> bool {
        self.entries.iter().any(|(k, _)| k == key)
    }

    /// Removes `key` and returns its values as text, if present.
    pub(crate) fn take_raw(&mut self, key: &str) -> Option<Vec<&'a str>> {
        self.take(key)
    }

    /// Removes `key` and returns its values, if present.
    fn take(&mut self, key: &str) -> Option<Vec<&'a str>> {
        let i = self.entries.iter().position(|(k, _)| k == key)?;
        Some(self.entries.remove(i).1)
    }

    fn numbers<T: std::str::FromStr + Copy>(&self, key: &str, values: &[&str], finite: impl Fn(T) -> bool) -> Result<Vec<T>, ParseError> {
        values
            .iter()
            .map(|v| match v.parse::<T>() {
                Ok(x) if finite(x) => Ok(x),
                Ok(_) => Err(self.error(format!("{key} value '{v}' is not finite"))),
                Err(_) => Err(self.error(format!("{key} value '{v}' is not a number"))),
            })
            .collect()
    }

    pub(crate) fn f32(&mut self, key: &str) -> Result<Option<f32>, ParseError> {
        let Some(values) = self.take(key) else { return Ok(None) };
        match self.numbers::<f32>(key, &values, f32::is_finite)?[..] {
            [x] => Ok(Some(x)),
            ref xs => Err(self.error(format!("{key} needs 1 number, got {}", xs.len()))),
        }
    }

    pub(crate) fn f64(&mut self, key: &str) -> Result<Option<f64>, ParseError> {
        let Some(values) = self.take(key) else { return Ok(None) };
        match self.numbers::<f64>(key, &values, f64::is_finite)?[..] {
            [x] => Ok(Some(x)),
            ref xs => Err(self.error(format!("{key} needs 1 number, got {}", xs.len()))),
        }
    }

    pub(crate) fn u32(&mut self, key: &str) -> Result<Option<u32>, ParseError> {
        let Some(values) = self.take(key) else { return Ok(None) };
        match values[..] {
            [v] => v.parse::<u32>().map(Some).map_err(|_| self.error(format!("{key} value '{v}' is not a whole number"))),
            _ => Err(self.error(format!("{key} needs 1 number, got {}", values.len()))),
        }
    }

    /// Exactly three numbers: a position or a direction.
    pub(crate) fn vec3(&mut self, key: &str) -> Result<Option<Vec3>, ParseError> {
        let Some(values) = self.take(key) else { return Ok(None) };
        match self.numbers::<f32>(key, &values, f32::is_finite)?[..] {
            [x, y, z] => Ok(Some(Vec3::new(x, y, z))),
            ref xs => Err(self.error(format!("{key} needs 3 numbers, got {}", xs.len()))),
        }
    }

    pub(crate) fn dvec3(&mut self, key: &str) -> Result<Option<DVec3>, ParseError> {
        let Some(values) = self.take(key) else { return Ok(None) };
        match self.numbers::<f64>(key, &values, f64::is_finite)?[..] {
            [x, y, z] => Ok(Some(DVec3::new(x, y, z))),
            ref xs => Err(self.error(format!("{key} needs 3 numbers, got {}", xs.len()))),
        }
    }

    /// An RGB colour: three numbers, or one meaning grey.
    pub(crate) fn rgb(&mut self, key: &str) -> Result<Option<Vec3>, ParseError> {
        let Some(values) = self.take(key) else { return Ok(None) };
        match self.numbers::<f32>(key, &values, f32::is_finite)?[..] {
            [v] => Ok(Some(Vec3::splat(v))),
            [r, g, b] => Ok(Some(Vec3::new(r, g, b))),
            ref xs => Err(self.error(format!("{key} needs 1 (grey) or 3 (RGB) numbers, got {}", xs.len()))),
        }
    }

    /// Fails on any key nobody asked for.
    pub(crate) fn finish(self, known: &str) -> Result<(), ParseError> {
        match self.entries.first() {
            None => Ok(()),
            Some((key, _)) => Err(self.error(format!("unknown key '{key}', expected {known}"))),
        }
    }
}

/// Writes numbers in the shortest text that parses back to the same value.
pub(crate) fn join<T: std::fmt::Display>(values: &[T]) -> String {
    values.iter().map(|v| v.to_string()).collect::<Vec<_>>().join(",")
}

/// An RGB colour, written as one number when it is grey.
pub(crate) fn rgb_text(c: Vec3) -> String {
    if c.x == c.y && c.y == c.z {
        c.x.to_string()
    } else {
        join(&c.to_array())
    }
}
