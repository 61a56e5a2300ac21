//! Reading Kalibr's YAML: the document, its keys, numbers and lists, each
//! failure a [`KalibrError`] naming the file and the key.

use yaml_rust2::{Yaml, YamlLoader};

use super::KalibrError;

/// Where errors point: the file.
pub(super) struct Doc<'a> {
    pub(super) path: &'a str,
}

impl Doc<'_> {
    pub(super) fn invalid(&self, key: &str, problem: impl Into<String>) -> KalibrError {
        KalibrError::Invalid {
            path: self.path.to_string(),
            key: key.to_string(),
            problem: problem.into(),
        }
    }

    pub(super) fn missing(&self, key: &str, hint: impl Into<String>) -> KalibrError {
        KalibrError::Missing {
            path: self.path.to_string(),
            key: key.to_string(),
            hint: hint.into(),
        }
    }

    /// The whole document: one YAML mapping.
    pub(super) fn load(&self, text: &str) -> Result<Yaml, KalibrError> {
        let not_yaml = |message: String| KalibrError::NotYaml {
            path: self.path.to_string(),
            message,
        };
        let docs = YamlLoader::load_from_str(text).map_err(|e| not_yaml(e.to_string()))?;
        let doc = docs
            .into_iter()
            .next()
            .ok_or_else(|| not_yaml("it holds no YAML document (empty file?)".into()))?;
        if !doc.is_hash() {
            return Err(not_yaml(format!(
                "its top level is {}, not a mapping of keys",
                kind(&doc)
            )));
        }
        Ok(doc)
    }

    /// `map[key]`, which must be there; `full` is its name in errors.
    pub(super) fn get<'y>(&self, map: &'y Yaml, key: &str, full: &str, hint: &str) -> Result<&'y Yaml, KalibrError> {
        match &map[key] {
            Yaml::BadValue => Err(self.missing(full, hint)),
            y => Ok(y),
        }
    }

    /// A finite number.
    pub(super) fn number(&self, y: &Yaml, key: &str) -> Result<f64, KalibrError> {
        let v = match y {
            Yaml::Integer(i) => *i as f64,
            Yaml::Real(s) => y
                .as_f64()
                .ok_or_else(|| self.invalid(key, format!("'{s}' is not a number")))?,
            Yaml::String(s) => return Err(self.invalid(key, format!("'{s}' is not a number"))),
            other => return Err(self.invalid(key, format!("expected a number, found {}", kind(other)))),
        };
        if !v.is_finite() {
            return Err(self.invalid(key, format!("{v} is not a finite number")));
        }
        Ok(v)
    }

    /// A list of exactly `N` finite numbers.
    pub(super) fn numbers<const N: usize>(&self, y: &Yaml, key: &str) -> Result<[f64; N], KalibrError> {
        let Yaml::Array(items) = y else {
            return Err(self.invalid(key, format!("expected a list of {N} numbers, found {}", kind(y))));
        };
        if items.len() != N {
            return Err(self.invalid(
                key,
                format!("expected a list of {N} numbers, found {} of them", items.len()),
            ));
        }
        let mut out = [0.0; N];
        for (i, item) in items.iter().enumerate() {
            out[i] = self.number(item, &format!("{key}[{i}]"))?;
        }
        Ok(out)
    }

    /// A positive whole number (a pixel count).
    pub(super) fn count(&self, y: &Yaml, key: &str) -> Result<u32, KalibrError> {
        let v = self.number(y, key)?;
        if v.fract() != 0.0 || v < 1.0 || v > u32::MAX as f64 {
            return Err(self.invalid(key, format!("{v} is not a positive whole number")));
        }
        Ok(v as u32)
    }

    pub(super) fn string<'y>(&self, y: &'y Yaml, key: &str) -> Result<&'y str, KalibrError> {
        match y {
            Yaml::String(s) => Ok(s),
            other => Err(self.invalid(key, format!("expected a name, found {}", kind(other)))),
        }
    }
}

/// What a YAML node is, for messages.
pub(super) fn kind(y: &Yaml) -> &'static str {
    match y {
        Yaml::Real(_) | Yaml::Integer(_) => "a number",
        Yaml::String(_) => "a string",
        Yaml::Boolean(_) => "a boolean",
        Yaml::Array(_) => "a list",
        Yaml::Hash(_) => "a mapping",
        Yaml::Alias(_) => "an alias",
        Yaml::Null => "nothing (an empty value)",
        Yaml::BadValue => "nothing",
    }
}
