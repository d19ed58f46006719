//! Parsing of procedural scene specs: `NAME?key=value&key=value`.

use std::collections::BTreeMap;
use std::str::FromStr;

/// A parsed `proc:` spec (without the `proc:` prefix): a name and its parameters.
/// Parameters are read with typed getters that reject malformed values; [`ProcSpec::finish`]
/// rejects parameters nobody read, so a typo never passes silently.
#[derive(Clone, Debug)]
pub struct ProcSpec {
    /// Scene name, e.g. `cloth`.
    pub name: String,
    params: BTreeMap<String, String>,
    used: std::cell::RefCell<Vec<String>>,
}

impl ProcSpec {
    /// Parses `NAME` or `NAME?k=v&k=v`.
    pub fn parse(s: &str) -> Result<Self, String> {
        let (name, query) = match s.split_once('?') {
            Some((n, q)) => (n, Some(q)),
            None => (s, None),
        };
        if name.is_empty() {
            return Err("missing procedural scene name (e.g. proc:cloth?n=10000)".into());
        }
        let mut params = BTreeMap::new();
        if let Some(q) = query {
            for kv in q.split('&').filter(|kv| !kv.is_empty()) {
                let (k, v) = kv
                    .split_once('=')
                    .ok_or_else(|| format!("parameter '{kv}' is not key=value"))?;
                if params.insert(k.to_string(), v.to_string()).is_some() {
                    return Err(format!("parameter '{k}' given twice"));
                }
            }
        }
        Ok(ProcSpec {
            name: name.to_string(),
            params,
            used: Default::default(),
        })
    }

    /// The parameter `key` parsed as `T`, or `default` when absent.
    pub fn get<T: FromStr>(&self, key: &str, default: T) -> Result<T, String> {
        self.used.borrow_mut().push(key.to_string());
        match self.params.get(key) {
            None => Ok(default),
            Some(v) => v
                .parse::<T>()
                .map_err(|_| format!("parameter {key}={v}: not a valid {}", short_type::<T>())),
        }
    }

    /// Like [`ProcSpec::get`], and checks `lo <= value <= hi`.
    pub fn get_in<T: FromStr + PartialOrd + std::fmt::Display + Copy>(
        &self,
        key: &str,
        default: T,
        lo: T,
        hi: T,
    ) -> Result<T, String> {
        let v = self.get(key, default)?;
        // Written so that NaN (incomparable) is rejected too.
        let inside = v >= lo && v <= hi;
        if !inside {
            return Err(format!("parameter {key}={v}: must be in [{lo}, {hi}]"));
        }
        Ok(v)
    }

    /// Fails if a parameter was given that no getter asked for.
    pub fn finish(&self) -> Result<(), String> {
        let used = self.used.borrow();
        let unknown: Vec<&str> = self
            .params
            .keys()
            .filter(|k| !used.iter().any(|u| u == *k))
            .map(|k| k.as_str())
            .collect();
        if unknown.is_empty() {
            Ok(())
        } else {
            Err(format!(
                "unknown parameter(s) for '{}': {} (known: {})",
                self.name,
                unknown.join(", "),
                used.join(", ")
            ))
        }
    }
}

fn short_type<T>() -> &'static str {
    let n = std::any::type_name::<T>();
    match n {
        "f32" | "f64" => "number",
        "u32" | "u64" | "usize" | "i32" | "i64" => "integer",
        _ => n,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_name_and_params() {
        let s = ProcSpec::parse("cloth?n=100000&seed=1").unwrap();
        assert_eq!(s.name, "cloth");
        assert_eq!(s.get::<usize>("n", 5).unwrap(), 100000);
        assert_eq!(s.get::<u64>("seed", 0).unwrap(), 1);
        assert_eq!(s.get::<f32>("amp", 0.5).unwrap(), 0.5);
        assert!(s.finish().is_ok());
    }

    #[test]
    fn rejects_bad_and_unknown_params() {
        assert!(ProcSpec::parse("").is_err());
        assert!(ProcSpec::parse("cloth?n").is_err());
        assert!(ProcSpec::parse("cloth?n=1&n=2").is_err());
        let s = ProcSpec::parse("cloth?n=abc&zzz=1").unwrap();
        assert!(s
            .get::<usize>("n", 1)
            .unwrap_err()
            .contains("not a valid integer"));
        assert!(s.finish().unwrap_err().contains("zzz"));
        let s = ProcSpec::parse("cloth?n=0").unwrap();
        assert!(s.get_in::<usize>("n", 1, 2, 10).is_err());
        let s = ProcSpec::parse("cloth?a=NaN").unwrap();
        assert!(s.get_in::<f32>("a", 1.0, 0.0, 10.0).is_err());
    }
}
