//! The text of ESI values: integers in decimal or `#x` hex, hex strings, booleans.

use crate::coe::{Entry, data_type};

/// An entry's value without a default: zeros of its size (a string: empty).
pub(super) fn zero_value(e: &Entry) -> Vec<u8> {
    match e.data_type {
        data_type::VISIBLE_STRING | data_type::OCTET_STRING | data_type::UNICODE_STRING => {
            Vec::new()
        }
        _ => vec![0; usize::from(e.bits).div_ceil(8)],
    }
}

/// A HexDecValue (ETG.2000): `#x` then hex digits, or a decimal number with an optional sign.
pub fn parse_int(s: &str) -> Option<i128> {
    let s = s.trim();
    if let Some(h) = s
        .strip_prefix("#x")
        .or_else(|| s.strip_prefix("#X"))
        .or_else(|| s.strip_prefix("0x"))
        .or_else(|| s.strip_prefix("0X"))
    {
        if h.is_empty() || h.len() > 32 {
            return None;
        }
        return u128::from_str_radix(h, 16)
            .ok()
            .and_then(|v| i128::try_from(v).ok());
    }
    if s.is_empty() || s.len() > 38 {
        return None;
    }
    s.parse::<i128>().ok()
}

/// xs:hexBinary, whitespace ignored.
pub fn parse_hex(s: &str) -> Option<Vec<u8>> {
    let digits: Vec<u8> = s.bytes().filter(|b| !b.is_ascii_whitespace()).collect();
    if !digits.len().is_multiple_of(2) {
        return None;
    }
    digits
        .chunks(2)
        .map(|p| {
            let h = char::from(p[0]).to_digit(16)?;
            let l = char::from(p[1]).to_digit(16)?;
            Some((h * 16 + l) as u8)
        })
        .collect()
}

pub(super) fn parse_bool(s: &str) -> Option<bool> {
    match s.trim() {
        "true" | "1" | "TRUE" | "True" => Some(true),
        "false" | "0" | "FALSE" | "False" => Some(false),
        _ => None,
    }
}

/// At most 40 characters of a value, for a message.
pub(super) fn shorten(s: &str) -> String {
    if s.chars().count() <= 40 {
        s.to_string()
    } else {
        format!("{}...", s.chars().take(40).collect::<String>())
    }
}
