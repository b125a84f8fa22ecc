//! The wire format. Every message between nodes and the host is encoded
//! and decoded here and nowhere else, with bincode 2 over serde (variable
//! width integers, little endian), so that the bytes counted per link are real
//! and the codec can be swapped in this one file (bincode is unmaintained;
//! 3.0.0 is a deliberate compile_error release, hence the pin to 2).
//! Messages travel in envelopes of stamped frames (`append_stamped`).

use serde::Serialize;
use serde::de::DeserializeOwned;

/// Variable-width integers: a path's sample number, fixed-point sums,
/// counts and indices are mostly small. Against fixed-width integers they
/// cut the bytes on the wire by 30% (the sphereflake at 1024x1024 on 32
/// nodes: 1.18 GB to 0.83 GB, 208 to 147 bytes per ray), which the
/// modelled links pay for, at 3-6% more host time to encode and decode.
fn config() -> bincode::config::Configuration<bincode::config::LittleEndian, bincode::config::Varint>
{
    bincode::config::standard()
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

/// Appends `body` to `envelope` as one stamped frame: its length (u32),
/// the virtual time at which its sender finishes sending it, which `stamp`
/// computes from the frame's length (the stamp itself is always 8 bytes,
/// an f64), and its bytes. Returns the frame's length.
///
/// An envelope is what moves over a link in one transfer: one or more
/// frames, each a message of the modelled machine. The emulation gathers
/// the messages a node sends during a slice of its work into one envelope
/// per link, so that a message costs the host one channel operation per
/// slice, not one each; the modelled costs are the frames' own.
pub fn append_stamped<T: Serialize>(
    envelope: &mut Vec<u8>,
    body: &T,
    stamp: impl FnOnce(usize) -> f64,
) -> Result<usize, String> {
    let start = envelope.len();
    envelope.extend_from_slice(&[0u8; 12]);
    if let Err(e) = bincode::serde::encode_into_std_write(body, envelope, config()) {
        envelope.truncate(start);
        return Err(format!("cannot encode: {e}"));
    }
    let len = envelope.len() - start;
    let Ok(len32) = u32::try_from(len) else {
        envelope.truncate(start);
        return Err(format!("a message of {len} bytes is too long to frame"));
    };
    let t = stamp(len);
    envelope[start..start + 4].copy_from_slice(&len32.to_le_bytes());
    envelope[start + 4..start + 12].copy_from_slice(&t.to_le_bytes());
    Ok(len)
}

/// An envelope of one stamped frame.
pub fn encode_stamped<T: Serialize>(
    body: &T,
    stamp: impl FnOnce(usize) -> f64,
) -> Result<Vec<u8>, String> {
    let mut envelope = Vec::new();
    append_stamped(&mut envelope, body, stamp)?;
    Ok(envelope)
}

/// The frames of an envelope: each one's stamp and message, in order.
pub fn decode_envelope<T: DeserializeOwned>(mut bytes: &[u8]) -> Result<Vec<(f64, T)>, String> {
    let mut out = Vec::new();
    while !bytes.is_empty() {
        let Some((head, _)) = bytes.split_first_chunk::<12>() else {
            return Err(format!("a frame of {} bytes has no header", bytes.len()));
        };
        let len = u32::from_le_bytes(head[..4].try_into().expect("4 bytes")) as usize;
        if len < 12 || len > bytes.len() {
            return Err(format!(
                "a frame claims {len} bytes where {} remain",
                bytes.len()
            ));
        }
        let stamp = f64::from_le_bytes(head[4..].try_into().expect("8 bytes"));
        out.push((stamp, decode(&bytes[12..len])?));
        bytes = &bytes[len..];
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    type Msg = Vec<(u32, f64, Option<String>)>;

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
        let mut env = encode_stamped(&v, |len| {
            seen = len;
            2.5
        })
        .unwrap();
        assert_eq!(seen, env.len());
        let n = append_stamped(&mut env, &vec![(3u32, 0.5f64, None::<String>)], |_| 4.0).unwrap();
        assert_eq!(env.len(), seen + n);
        let back: Vec<(f64, Msg)> = decode_envelope(&env).unwrap();
        assert_eq!(back.len(), 2);
        assert_eq!((back[0].0, &back[0].1), (2.5, &v));
        assert_eq!((back[1].0, back[1].1[0].0), (4.0, 3));
        assert!(decode_envelope::<u8>(&[1, 2]).is_err());
        assert!(decode_envelope::<u8>(&env[..env.len() - 1]).is_err());
    }
}
