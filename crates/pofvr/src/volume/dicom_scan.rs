//! A walk over a DICOM file's element headers before dicom-rs parses it: every defined
//! length must fit in what is left of the file. The parser reserves each element's claimed
//! length before reading it, so a damaged length (one flipped byte) would otherwise ask
//! for gigabytes from a file of a few hundred bytes.
//!
//! The walk descends into sequences and items (their elements have lengths of their own)
//! and steps over the fragments of encapsulated pixel data. Deflated data sets are not
//! walked (their bytes are not element headers).

use dicom_core::dictionary::{DataDictionary, DataDictionaryEntry};
use dicom_core::{Tag, VR};
use dicom_dictionary_std::StandardDataDictionary;

const UNDEFINED: u32 = 0xFFFF_FFFF;
const PIXEL_DATA: Tag = Tag(0x7FE0, 0x0010);
const TRANSFER_SYNTAX: Tag = Tag(0x0002, 0x0010);

/// Where the walk stopped: the element and what is wrong.
#[derive(Debug)]
pub(super) struct Bad {
    pub tag: Option<Tag>,
    pub why: String,
}

fn bad(tag: Option<Tag>, why: String) -> Bad {
    Bad { tag, why }
}

/// Checks the element lengths of the Part 10 file `bytes` (preamble, `DICM`, meta group,
/// data set).
pub(super) fn check_lengths(bytes: &[u8]) -> Result<(), Bad> {
    if bytes.len() < 132 || &bytes[128..132] != b"DICM" {
        return Err(bad(
            None,
            "no DICM magic after the 128-byte preamble".into(),
        ));
    }
    // The meta group is explicit VR little endian whatever the data set's syntax.
    let mut w = Walk {
        bytes,
        pos: 132,
        explicit: true,
        big: false,
        fragments: false,
        ts: None,
    };
    w.run(true)?;
    let ts = w.ts.take().unwrap_or_default();
    let ts = ts.trim_end_matches(['\0', ' ']);
    if ts == "1.2.840.10008.1.2.1.99" {
        return Ok(());
    }
    w.explicit = ts != "1.2.840.10008.1.2";
    w.big = ts == "1.2.840.10008.1.2.2";
    w.run(false)
}

struct Walk<'a> {
    bytes: &'a [u8],
    pos: usize,
    explicit: bool,
    big: bool,
    /// Inside encapsulated pixel data: items are opaque fragments.
    fragments: bool,
    ts: Option<String>,
}

impl Walk<'_> {
    fn u16_at(&self, at: usize) -> u16 {
        let b = [self.bytes[at], self.bytes[at + 1]];
        if self.big {
            u16::from_be_bytes(b)
        } else {
            u16::from_le_bytes(b)
        }
    }

    fn u32_at(&self, at: usize) -> u32 {
        let b = [
            self.bytes[at],
            self.bytes[at + 1],
            self.bytes[at + 2],
            self.bytes[at + 3],
        ];
        if self.big {
            u32::from_be_bytes(b)
        } else {
            u32::from_le_bytes(b)
        }
    }

    /// Walks elements until the end (or, for the meta group, its last element).
    fn run(&mut self, meta: bool) -> Result<(), Bad> {
        while self.pos < self.bytes.len() {
            let left = self.bytes.len() - self.pos;
            if left < 8 {
                return Err(bad(
                    None,
                    format!(
                        "{left} stray bytes at offset {} (an element header is 8)",
                        self.pos
                    ),
                ));
            }
            let tag = Tag(self.u16_at(self.pos), self.u16_at(self.pos + 2));
            if meta && tag.group() != 0x0002 {
                return Ok(());
            }
            if tag.group() == 0xFFFE {
                // Items and delimiters: a tag and a 4-byte length, never a VR.
                let len = self.u32_at(self.pos + 4);
                self.pos += 8;
                match tag.element() {
                    0xE000 if self.fragments && len != UNDEFINED => self.skip(tag, len)?,
                    0xE000 if len != UNDEFINED => self.fits(tag, len)?,
                    0xE0DD => self.fragments = false,
                    _ => {}
                }
                continue;
            }
            let (vr, len, header) = if self.explicit {
                let vr = [self.bytes[self.pos + 4], self.bytes[self.pos + 5]];
                // As dicom-rs reads them: these VRs have a 2-byte length, every other one
                // (an unknown VR too, read as UN) a reserved field and a 4-byte length.
                let short = matches!(
                    &vr,
                    b"AE"
                        | b"AS"
                        | b"AT"
                        | b"CS"
                        | b"DA"
                        | b"DS"
                        | b"DT"
                        | b"FL"
                        | b"FD"
                        | b"IS"
                        | b"LO"
                        | b"LT"
                        | b"PN"
                        | b"SH"
                        | b"SL"
                        | b"SS"
                        | b"ST"
                        | b"TM"
                        | b"UI"
                        | b"UL"
                        | b"US"
                );
                if !short {
                    if left < 12 {
                        return Err(bad(Some(tag), "truncated element header".into()));
                    }
                    let vr = VR::from_binary(vr).unwrap_or(VR::UN);
                    (Some(vr), self.u32_at(self.pos + 8), 12)
                } else {
                    (VR::from_binary(vr), u32::from(self.u16_at(self.pos + 6)), 8)
                }
            } else {
                let vr = StandardDataDictionary.by_tag(tag).map(|e| e.vr().relaxed());
                (vr, self.u32_at(self.pos + 4), 8)
            };
            self.pos += header;
            let sequence = vr == Some(VR::SQ);
            if len == UNDEFINED {
                // A sequence, an implicit-VR sequence in UN, or encapsulated pixel data.
                if !sequence && tag == PIXEL_DATA {
                    self.fragments = true;
                }
                continue;
            }
            if sequence {
                // Its items follow: walked, not skipped.
                self.fits(tag, len)?;
                continue;
            }
            if meta && tag == TRANSFER_SYNTAX {
                self.fits(tag, len)?;
                let v = &self.bytes[self.pos..self.pos + len as usize];
                self.ts = Some(String::from_utf8_lossy(v).into_owned());
            }
            self.skip(tag, len)?;
        }
        Ok(())
    }

    fn fits(&self, tag: Tag, len: u32) -> Result<(), Bad> {
        let left = self.bytes.len() - self.pos;
        if len as usize > left {
            return Err(bad(
                Some(tag),
                format!(
                    "claims {len} bytes at offset {}, and the file has {left} left",
                    self.pos
                ),
            ));
        }
        Ok(())
    }

    fn skip(&mut self, tag: Tag, len: u32) -> Result<(), Bad> {
        self.fits(tag, len)?;
        self.pos += len as usize;
        Ok(())
    }
}
