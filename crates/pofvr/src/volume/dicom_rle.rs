//! RLE Lossless pixel data (DICOM PS3.5 Annex G), decoded here rather than by dicom-rs,
//! whose decoder indexes past short segments and trusts the segment header: every offset
//! and run is checked against the fragment, and the output is exactly one frame.

/// The frame of `rows × cols` grey pixels of `bytes_per_sample` bytes (1 or 2) in the RLE
/// fragments `fragments` (one frame: their bytes concatenated), little-endian.
///
/// # Errors
/// What is wrong with the data: a bad segment header, a segment outside the data, or a
/// segment that decodes to fewer bytes than the frame needs.
pub(super) fn decode(
    fragments: &[Vec<u8>],
    rows: usize,
    cols: usize,
    bytes_per_sample: usize,
) -> Result<Vec<u8>, String> {
    let data: Vec<u8> = fragments.concat();
    if data.len() < 64 {
        return Err(format!(
            "{} bytes: shorter than the 64-byte RLE header",
            data.len()
        ));
    }
    let word = |i: usize| u32::from_le_bytes([data[i], data[i + 1], data[i + 2], data[i + 3]]);
    let segments = word(0) as usize;
    if segments != bytes_per_sample {
        return Err(format!(
            "{segments} RLE segments, expected {bytes_per_sample} (one per byte of a grey sample)"
        ));
    }
    let offsets: Vec<usize> = (0..segments).map(|s| word(4 + 4 * s) as usize).collect();
    let n = rows * cols;
    let mut planes = Vec::with_capacity(segments);
    for s in 0..segments {
        let start = offsets[s];
        let end = offsets.get(s + 1).copied().unwrap_or(data.len());
        if start < 64 || start > end || end > data.len() {
            return Err(format!(
                "RLE segment {s} at bytes {start}..{end} of {}",
                data.len()
            ));
        }
        planes.push(pack_bits(&data[start..end], n).map_err(|got| {
            format!("RLE segment {s} decodes to {got} bytes, the frame needs {n}")
        })?);
    }
    if bytes_per_sample == 1 {
        return Ok(planes.swap_remove(0));
    }
    // Segment 0 holds the high bytes, segment 1 the low ones.
    let mut out = Vec::with_capacity(2 * n);
    for (hi, lo) in planes[0].iter().zip(&planes[1]) {
        out.push(*lo);
        out.push(*hi);
    }
    Ok(out)
}

/// The first `n` bytes PackBits-decoded from `src`; `Err(len)` when it holds fewer.
fn pack_bits(src: &[u8], n: usize) -> Result<Vec<u8>, usize> {
    let mut out = Vec::with_capacity(n.min(src.len().saturating_mul(64)));
    let mut i = 0;
    while out.len() < n && i < src.len() {
        let h = src[i] as i8;
        i += 1;
        if h >= 0 {
            // A literal run of h + 1 bytes.
            let k = (h as usize + 1).min(src.len() - i);
            out.extend_from_slice(&src[i..i + k]);
            i += k;
        } else if h != -128 {
            // One byte repeated 1 - h times.
            let Some(&b) = src.get(i) else { break };
            i += 1;
            out.resize(out.len() + (1 - isize::from(h)) as usize, b);
        }
    }
    if out.len() < n {
        return Err(out.len());
    }
    out.truncate(n);
    Ok(out)
}

#[cfg(test)]
mod test {
    use super::{decode, pack_bits};

    #[test]
    fn pack_bits_decodes_literals_and_runs() {
        assert_eq!(
            pack_bits(&[2, 1, 2, 3, 0xFE, 9], 6),
            Ok(vec![1, 2, 3, 9, 9, 9])
        );
        assert_eq!(pack_bits(&[0x80, 0, 7], 1), Ok(vec![7]));
        // Short data: an error with what it decoded, never an index past the end.
        assert_eq!(pack_bits(&[5, 1, 2], 6), Err(2));
        assert_eq!(pack_bits(&[0xFE], 3), Err(0));
    }

    #[test]
    fn bad_headers_and_segments_are_errors() {
        let mut frag = vec![0u8; 64];
        frag[0] = 2;
        frag[4] = 64;
        frag[8] = 200; // past the end
        frag.extend([0, 5, 0, 6]);
        let e = decode(&[frag.clone()], 1, 2, 2).unwrap_err();
        assert!(e.contains("64..200 of 68"), "{e}");
        frag[8] = 66;
        // Segment 0: literal [5]; segment 1: literal [6]: one 16-bit pixel 0x0506.
        assert_eq!(decode(&[frag.clone()], 1, 1, 2), Ok(vec![6, 5]));
        assert!(decode(&[frag[..10].to_vec()], 1, 1, 2).is_err());
        frag[0] = 9;
        assert!(decode(&[frag], 1, 1, 2)
            .unwrap_err()
            .contains("9 RLE segments"));
    }
}
