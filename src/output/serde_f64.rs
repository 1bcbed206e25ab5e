//! serde `with` helper for f64 that may be NaN or infinite (a member that never reached the
//! threshold, an ok member's failure time, an empty statistic's min): JSON has no NaN, so
//! non-finite values travel as the strings "NaN", "inf", "-inf"; finite ones as numbers, which
//! serde_json (with its `float_roundtrip` feature) writes in the shortest form that parses back
//! to the same bits, and reads back exactly. Reading accepts a number or a string holding one.
//! CSV writes the same text as JSON.

use serde::{de, Deserializer, Serializer};

pub fn serialize<S: Serializer>(x: &f64, s: S) -> Result<S::Ok, S::Error> {
    if x.is_finite() {
        s.serialize_f64(*x)
    } else if x.is_nan() {
        s.serialize_str("NaN")
    } else if *x > 0.0 {
        s.serialize_str("inf")
    } else {
        s.serialize_str("-inf")
    }
}

struct Visitor;
impl de::Visitor<'_> for Visitor {
    type Value = f64;
    fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
        f.write_str("a number, or \"NaN\", \"inf\", \"-inf\"")
    }
    fn visit_f64<E: de::Error>(self, v: f64) -> Result<f64, E> {
        Ok(v)
    }
    fn visit_i64<E: de::Error>(self, v: i64) -> Result<f64, E> {
        Ok(v as f64)
    }
    fn visit_u64<E: de::Error>(self, v: u64) -> Result<f64, E> {
        Ok(v as f64)
    }
    fn visit_str<E: de::Error>(self, v: &str) -> Result<f64, E> {
        v.trim()
            .parse::<f64>()
            .map_err(|_| E::custom(format!("not a number: {v:?}")))
    }
}

pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
    d.deserialize_any(Visitor)
}
