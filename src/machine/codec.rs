//! The wire format. Every message between nodes and the host is encoded
//! and decoded here and nowhere else, with bincode 2 over serde (fixed-width
//! integers, little endian), so that the bytes counted per link are real
//! and the codec can be swapped in this one file (bincode is unmaintained;
//! 3.0.0 is a deliberate compile_error release, hence the pin to 2).

use serde::Serialize;
use serde::de::DeserializeOwned;

/// Fixed-width integers: a little larger than varints on the wire, but
/// encoding and decoding, which every hop pays on a node, cost less.
fn config() -> bincode::config::Configuration<bincode::config::LittleEndian, bincode::config::Fixint>
{
    bincode::config::standard().with_fixed_int_encoding()
}

/// The bytes of a message.
pub fn encode<T: Serialize>(msg: &T) -> Result<Vec<u8>, String> {
    bincode::serde::encode_to_vec(msg, config()).map_err(|e| format!("cannot encode: {e}"))
}

/// A message from its bytes; every byte must be used.
pub fn decode<T: DeserializeOwned>(bytes: &[u8]) -> Result<T, String> {
    let (msg, used) = bincode::serde::decode_from_slice(bytes, config())
        .map_err(|e| format!("cannot decode a message of {} bytes: {e}", bytes.len()))?;
    if used != bytes.len() {
        return Err(format!(
            "a message of {} bytes has {} trailing bytes",
            bytes.len(),
            bytes.len() - used
        ));
    }
    Ok(msg)
}

/// The bytes of `body` behind a stamp: the virtual time at which its
/// sender finishes sending it, which `stamp` computes from the message's
/// length (the stamp itself is always 8 bytes, an f64).
pub fn encode_stamped<T: Serialize>(
    body: &T,
    stamp: impl FnOnce(usize) -> f64,
) -> Result<Vec<u8>, String> {
    let mut bytes = vec![0u8; 8];
    bincode::serde::encode_into_std_write(body, &mut bytes, config())
        .map_err(|e| format!("cannot encode: {e}"))?;
    let t = stamp(bytes.len());
    bytes[..8].copy_from_slice(&t.to_le_bytes());
    Ok(bytes)
}

/// The stamp and body of a message from `encode_stamped`.
pub fn decode_stamped<T: DeserializeOwned>(bytes: &[u8]) -> Result<(f64, T), String> {
    let Some((stamp, body)) = bytes.split_first_chunk::<8>() else {
        return Err(format!("a message of {} bytes has no stamp", bytes.len()));
    };
    Ok((f64::from_le_bytes(*stamp), decode(body)?))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_and_rejects_garbage() {
        let v: Vec<(u32, f64, Option<String>)> =
            vec![(1, -0.0, None), (7, 1e300, Some("x".into()))];
        let b = encode(&v).unwrap();
        let back: Vec<(u32, f64, Option<String>)> = decode(&b).unwrap();
        assert_eq!(back[0].1.to_bits(), (-0.0f64).to_bits());
        assert_eq!(back, v);
        let mut long = b.clone();
        long.push(0);
        assert!(decode::<Vec<(u32, f64, Option<String>)>>(&long).is_err());
        assert!(decode::<Vec<(u32, f64, Option<String>)>>(&b[..b.len() - 1]).is_err());
        let mut seen = 0;
        let s = encode_stamped(&v, |len| {
            seen = len;
            2.5
        })
        .unwrap();
        assert_eq!(seen, s.len());
        let (t, back): (f64, Vec<(u32, f64, Option<String>)>) = decode_stamped(&s).unwrap();
        assert_eq!((t, back), (2.5, v));
        assert!(decode_stamped::<u8>(&[1, 2]).is_err());
    }
}
