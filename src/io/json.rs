//! JSON through `serde_json`: documents parsed with errors that name the line, arrays of
//! numbers, and records written one per line (training logs, `--json` outputs).
//!
//! JSON has no NaN or infinity: a non-finite number is written as `null` and [`number`] reads
//! `null` back as NaN. [`parse_lenient`] also reads the bare `NaN`, `inf` and `-inf` tokens
//! that training logs of earlier versions hold.

use crate::error::{Error, Result};
use serde::Serialize;
use std::string::String;
use std::vec::Vec;

pub use serde_json::Value;

fn parse_error(e: &serde_json::Error) -> Error {
    Error::parse("json", e.line(), std::format!("{e}"))
}

/// Parses a complete JSON document (objects keep their key order).
///
/// # Errors
/// [`Error::Parse`] with format `"json"` and the 1-based line of the problem.
pub fn parse(text: &str) -> Result<Value> {
    serde_json::from_str(text).map_err(|e| parse_error(&e))
}

/// As [`parse`], reading the tokens `NaN`, `inf` and `-inf` outside strings as `null`.
///
/// # Errors
/// As [`parse`].
pub fn parse_lenient(text: &str) -> Result<Value> {
    match serde_json::from_str(text) {
        Ok(v) => Ok(v),
        Err(first) => {
            let fixed = non_finite_as_null(text);
            if fixed == text {
                return Err(parse_error(&first));
            }
            parse(&fixed)
        }
    }
}

/// `text` with every `NaN`, `inf` and `-inf` outside a string replaced by `null`.
fn non_finite_as_null(text: &str) -> String {
    let mut out = String::with_capacity(text.len());
    let (mut in_string, mut escaped) = (false, false);
    let mut rest = text;
    while let Some(c) = rest.chars().next() {
        if in_string {
            (in_string, escaped) = (escaped || c != '"', !escaped && c == '\\');
        } else if c == '"' {
            in_string = true;
        } else if let Some(token) = ["NaN", "-inf", "inf"].into_iter().find(|t| rest.starts_with(t)) {
            out.push_str("null");
            rest = &rest[token.len()..];
            continue;
        }
        out.push(c);
        rest = &rest[c.len_utf8()..];
    }
    out
}

/// The number `v` holds, NaN for `null` (a non-finite number written by [`to_line`]).
pub fn number(v: &Value) -> Option<f64> {
    match v {
        Value::Null => Some(f64::NAN),
        v => v.as_f64(),
    }
}

/// An array of numbers as `f64`s, if `v` is one.
pub fn f64_vec(v: &Value) -> Option<Vec<f64>> {
    v.as_array()?.iter().map(Value::as_f64).collect()
}

/// `value` as one line of JSON (no newline; non-finite numbers as `null`).
pub fn to_line<T: Serialize + ?Sized>(value: &T) -> String {
    // Serialising plain structs, numbers and strings to memory cannot fail.
    serde_json::to_string(value).unwrap_or_default()
}

/// `value` as indented JSON, ending in a newline (non-finite numbers as `null`).
pub fn to_pretty<T: Serialize + ?Sized>(value: &T) -> String {
    let mut s = serde_json::to_string_pretty(value).unwrap_or_default();
    s.push('\n');
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn json_parses_documents_in_key_order() {
        let v = parse(r#" {"z": [1, -2.5e1, true, null], "b\"": {"c": "x\u00e9\n"}, "e": []} "#).unwrap();
        assert_eq!(v["z"].as_array().unwrap().len(), 4);
        assert_eq!(v["z"][1].as_f64(), Some(-25.0));
        assert_eq!(v["b\""]["c"].as_str(), Some("xé\n"));
        let keys: Vec<&str> = v.as_object().unwrap().keys().map(String::as_str).collect();
        assert_eq!(keys, ["z", "b\"", "e"]);
        assert_eq!(f64_vec(&parse("[0.5, 3]").unwrap()), Some(std::vec![0.5, 3.0]));
        assert_eq!(f64_vec(&parse("[0.5, \"3\"]").unwrap()), None);
    }

    #[test]
    fn json_errors_name_the_line() {
        let e = parse("{\n\"a\": 1,\n\"b\": tru }").unwrap_err();
        assert!(matches!(e, Error::Parse { format: "json", line: 3, .. }), "{e:?}");
        for bad in ["[1, 2", "{\"a\" 1}", "[1] x", "\"abc", "[NaN]"] {
            assert!(parse(bad).is_err(), "{bad}");
        }
        assert!(parse(&"[".repeat(1000)).is_err());
    }

    #[test]
    fn strings_with_quotes_and_newlines_round_trip() {
        #[derive(Serialize)]
        struct Row<'a> {
            scene: &'a str,
            total: f64,
        }
        let name = "a \"quoted\"\nname\\with\ttabs";
        let line = to_line(&Row { scene: name, total: 1.5 });
        assert!(!line.contains('\n'), "{line}");
        let back = parse(&line).unwrap();
        assert_eq!(back["scene"].as_str(), Some(name));
        assert_eq!(number(&back["total"]), Some(1.5));
    }

    #[test]
    fn non_finite_numbers_write_null_and_read_back_as_nan() {
        let line = to_line(&[f64::NAN, f64::INFINITY, 2.0]);
        assert_eq!(line, "[null,null,2.0]");
        let back = parse(&line).unwrap();
        assert!(number(&back[0]).unwrap().is_nan());
        assert_eq!(number(&back[2]), Some(2.0));
        assert!(number(&Value::from("x")).is_none());
        let pretty = to_pretty(&[f32::NAN]);
        assert!(parse(&pretty).unwrap()[0].is_null());
    }

    #[test]
    fn lenient_parsing_reads_bare_non_finite_tokens_outside_strings() {
        let old = r#"{"total":NaN,"b":[inf,-inf,1e0],"scene":"NaN inf \"x\""}"#;
        let v = parse_lenient(old).unwrap();
        assert!(v["total"].is_null());
        assert!(v["b"][0].is_null() && v["b"][1].is_null());
        assert_eq!(v["b"][2].as_f64(), Some(1.0));
        assert_eq!(v["scene"].as_str(), Some("NaN inf \"x\""));
        assert!(parse_lenient("{\"a\": nope}").is_err());
    }
}
