//! Serde glue of the wire maps: a field that must be present even when `nil`, nested structs
//! read only from msgpack maps (never from arrays, which serde would accept), and the pose.

use rmpv::Value;
use serde::de::{DeserializeOwned, Error as _};
use serde::{Deserialize, Deserializer};

/// A field that must be present but may be `nil` (serde would default a missing `Option`).
pub(crate) fn nullable<'de, D: Deserializer<'de>, T: Deserialize<'de>>(
    d: D,
) -> Result<Option<T>, D::Error> {
    Option::<T>::deserialize(d)
}

/// A nested struct: only from a msgpack map, never from an array.
pub(crate) fn nested<'de, D: Deserializer<'de>, T: DeserializeOwned>(d: D) -> Result<T, D::Error> {
    let value = Value::deserialize(d)?;
    from_value(value).map_err(D::Error::custom)
}

pub(crate) fn nested_list<'de, D: Deserializer<'de>, T: DeserializeOwned>(
    d: D,
) -> Result<Vec<T>, D::Error> {
    Vec::<Value>::deserialize(d)?
        .into_iter()
        .map(|value| from_value(value).map_err(D::Error::custom))
        .collect()
}

/// Deserialize a value that must be a msgpack map (a struct never comes from an array).
pub(crate) fn from_value<T: DeserializeOwned>(value: Value) -> Result<T, rmpv::ext::Error> {
    if !value.is_map() {
        return Err(serde::de::Error::custom(format!(
            "expected a map, got a msgpack {}",
            kind_of(&value)
        )));
    }
    rmpv::ext::from_value(value)
}

/// The msgpack kind of a value, as error messages name it.
pub(crate) fn kind_of(value: &Value) -> &'static str {
    match value {
        Value::Nil => "nil",
        Value::Boolean(_) => "bool",
        Value::Integer(_) => "int",
        Value::F32(_) | Value::F64(_) => "float",
        Value::String(_) => "str",
        Value::Binary(_) => "bin",
        Value::Array(_) => "array",
        Value::Map(_) => "map",
        Value::Ext(..) => "ext",
    }
}

pub(crate) fn pose<'de, D: Deserializer<'de>>(d: D) -> Result<Option<[f64; 3]>, D::Error> {
    match Option::<Vec<f64>>::deserialize(d)? {
        None => Ok(None),
        Some(values) => <[f64; 3]>::try_from(values.as_slice())
            .map(Some)
            .map_err(|_| D::Error::custom(format!("a pose has 3 values, not {}", values.len()))),
    }
}
