//! A parquet file's page headers checked before its reader trusts them.
//!
//! parquet 60.1 reserves a page's declared `uncompressed_page_size` (an i32: up to 2 GiB) before it decompresses
//! the page, so a damaged 46 kB episodes file made it ask for 2 GiB (mars-fuzz, `lerobot-episodes`). Each column
//! chunk's pages are walked here first, from the footer's byte ranges, and a page declaring more than
//! [`MAX_PAGE_BYTES`] (or sizes that leave its chunk) refuses the file.
//!
//! The headers are Thrift compact-protocol structs. The `thrift` crate reads them, but it reserves a binary
//! field's declared length before reading it — the same trust in a size — so this walks the encoding itself,
//! skipping what it does not need without allocating.

use parquet::file::metadata::ParquetMetaData;

/// The largest page a LeRobot file may declare: writers cut pages at ~1 MiB, and a page holds at least one value
/// (an image in a data file is far below this).
pub const MAX_PAGE_BYTES: usize = 256 << 20;

/// Nested structs and containers deeper than this are refused (a page header nests three levels).
const MAX_DEPTH: usize = 16;

/// Every page of every column chunk of `file` (its whole bytes; `meta` its footer, which parquet has read).
pub fn check(file: &[u8], meta: &ParquetMetaData) -> Result<(), String> {
    for (g, group) in meta.row_groups().iter().enumerate() {
        for (c, column) in group.columns().iter().enumerate() {
            let (start, len) = column.byte_range();
            let chunk = usize::try_from(start)
                .ok()
                .zip(usize::try_from(len).ok())
                .and_then(|(s, l)| file.get(s..s.checked_add(l)?))
                .ok_or_else(|| format!("row group {g} column {c}: its bytes {start}+{len} leave the file"))?;
            check_chunk(chunk).map_err(|e| format!("row group {g} column {c}: {e}"))?;
        }
    }
    Ok(())
}

/// The pages of one column chunk, header after header.
fn check_chunk(chunk: &[u8]) -> Result<(), String> {
    let mut at = 0;
    while at < chunk.len() {
        let mut r = Reader { buf: &chunk[at..], at: 0 };
        let sizes = r.page_header().map_err(|e| format!("the page header at byte {at}: {e}"))?;
        if sizes.uncompressed > MAX_PAGE_BYTES {
            return Err(format!(
                "a page declares {} bytes uncompressed (at most {MAX_PAGE_BYTES})",
                sizes.uncompressed
            ));
        }
        at = (at + r.at)
            .checked_add(sizes.compressed)
            .filter(|&end| end <= chunk.len())
            .ok_or_else(|| format!("a page of {} bytes leaves its column chunk", sizes.compressed))?;
    }
    Ok(())
}

struct PageSizes {
    uncompressed: usize,
    compressed: usize,
}

/// A cursor over Thrift compact-protocol bytes.
struct Reader<'a> {
    buf: &'a [u8],
    at: usize,
}

impl Reader<'_> {
    /// PageHeader: field 2 is `uncompressed_page_size`, field 3 `compressed_page_size` (both i32).
    fn page_header(&mut self) -> Result<PageSizes, String> {
        let (mut uncompressed, mut compressed) = (None, None);
        let mut last_id = 0i16;
        while let Some((id, kind)) = self.field_header(&mut last_id)? {
            match (id, kind) {
                (2, I32) => uncompressed = Some(self.size()?),
                (3, I32) => compressed = Some(self.size()?),
                _ => self.skip(kind, 0)?,
            }
        }
        match (uncompressed, compressed) {
            (Some(uncompressed), Some(compressed)) => Ok(PageSizes { uncompressed, compressed }),
            _ => Err("no page sizes".into()),
        }
    }

    fn byte(&mut self) -> Result<u8, String> {
        let b = *self.buf.get(self.at).ok_or("cut short")?;
        self.at += 1;
        Ok(b)
    }

    fn advance(&mut self, n: u64) -> Result<(), String> {
        let n = usize::try_from(n).map_err(|_| "cut short")?;
        let end = self.at.checked_add(n).filter(|&e| e <= self.buf.len()).ok_or("cut short")?;
        self.at = end;
        Ok(())
    }

    fn varint(&mut self) -> Result<u64, String> {
        let mut v = 0u64;
        for shift in (0..64).step_by(7) {
            let b = self.byte()?;
            v |= u64::from(b & 0x7f) << shift;
            if b & 0x80 == 0 {
                return Ok(v);
            }
        }
        Err("a varint longer than 10 bytes".into())
    }

    fn zigzag(&mut self) -> Result<i64, String> {
        let v = self.varint()?;
        Ok((v >> 1) as i64 ^ -((v & 1) as i64))
    }

    /// A page size: an i32 that must not be negative.
    fn size(&mut self) -> Result<usize, String> {
        let v = self.zigzag()?;
        usize::try_from(i32::try_from(v).map_err(|_| "a size past i32")?).map_err(|_| format!("a negative size {v}"))
    }

    /// The next field's id and type, or `None` at the struct's end.
    fn field_header(&mut self, last_id: &mut i16) -> Result<Option<(i16, u8)>, String> {
        let b = self.byte()?;
        if b == 0 {
            return Ok(None);
        }
        let (delta, kind) = (b >> 4, b & 0x0f);
        let id = if delta == 0 {
            i16::try_from(self.zigzag()?).map_err(|_| "a field id past i16")?
        } else {
            last_id.checked_add(i16::from(delta)).ok_or("a field id past i16")?
        };
        *last_id = id;
        Ok(Some((id, kind)))
    }

    /// Skips one value of compact type `kind` (as a field's type: booleans carry their value in it).
    fn skip(&mut self, kind: u8, depth: usize) -> Result<(), String> {
        if depth > MAX_DEPTH {
            return Err("nested too deep".into());
        }
        match kind {
            BOOL_TRUE | BOOL_FALSE => Ok(()),
            BYTE => self.advance(1),
            I16 | I32 | I64 => self.varint().map(drop),
            DOUBLE => self.advance(8),
            BINARY => {
                let n = self.varint()?;
                self.advance(n)
            }
            LIST | SET => self.skip_list(depth),
            MAP => self.skip_map(depth),
            STRUCT => self.skip_struct(depth),
            _ => Err(format!("an unknown type {kind}")),
        }
    }

    fn skip_struct(&mut self, depth: usize) -> Result<(), String> {
        let mut last_id = 0i16;
        while let Some((_, kind)) = self.field_header(&mut last_id)? {
            self.skip(kind, depth + 1)?;
        }
        Ok(())
    }

    fn skip_list(&mut self, depth: usize) -> Result<(), String> {
        let b = self.byte()?;
        let n = if b >> 4 == 15 { self.varint()? } else { u64::from(b >> 4) };
        // Each element takes at least a byte, so a count past the bytes left fails at the end of the input.
        for _ in 0..n {
            self.element(b & 0x0f, depth)?;
        }
        Ok(())
    }

    fn skip_map(&mut self, depth: usize) -> Result<(), String> {
        let n = self.varint()?;
        if n == 0 {
            return Ok(());
        }
        let kinds = self.byte()?;
        for _ in 0..n {
            self.element(kinds >> 4, depth)?;
            self.element(kinds & 0x0f, depth)?;
        }
        Ok(())
    }

    /// An element of a container: a boolean is a byte here.
    fn element(&mut self, kind: u8, depth: usize) -> Result<(), String> {
        match kind {
            BOOL_TRUE | BOOL_FALSE => self.advance(1),
            _ => self.skip(kind, depth + 1),
        }
    }
}

const BOOL_TRUE: u8 = 1;
const BOOL_FALSE: u8 = 2;
const BYTE: u8 = 3;
const I16: u8 = 4;
const I32: u8 = 5;
const I64: u8 = 6;
const DOUBLE: u8 = 7;
const BINARY: u8 = 8;
const LIST: u8 = 9;
const SET: u8 = 10;
const MAP: u8 = 11;
const STRUCT: u8 = 12;

#[cfg(test)]
mod tests {
    use super::*;

    /// A compact PageHeader: type DATA_PAGE (0), the two sizes, a data_page_header with statistics (a binary).
    fn header(uncompressed: i32, compressed: i32) -> Vec<u8> {
        let zz = |v: i32| {
            let mut z = ((v << 1) ^ (v >> 31)) as u32;
            let mut out = Vec::new();
            loop {
                let b = (z & 0x7f) as u8;
                z >>= 7;
                if z == 0 {
                    out.push(b);
                    return out;
                }
                out.push(b | 0x80);
            }
        };
        let mut h = vec![0x15];
        h.extend(zz(0));
        h.push(0x15);
        h.extend(zz(uncompressed));
        h.push(0x15);
        h.extend(zz(compressed));
        // field 5 (delta 2): data_page_header { 1: num_values i32, 5: statistics { 1: max binary "ab" } }
        h.extend([0x2c, 0x15]);
        h.extend(zz(3));
        h.extend([0x4c, 0x18, 2, b'a', b'b', 0, 0, 0]);
        h
    }

    fn chunk(pages: &[(i32, i32)]) -> Vec<u8> {
        let mut c = Vec::new();
        for &(u, k) in pages {
            c.extend(header(u, k));
            c.extend(std::iter::repeat_n(7u8, k as usize));
        }
        c
    }

    #[test]
    fn pages_within_the_limit_and_the_chunk_pass() {
        assert_eq!(check_chunk(&chunk(&[(10, 4), (1 << 20, 3)])), Ok(()));
    }

    #[test]
    fn a_page_declaring_gigabytes_is_refused_before_anything_is_reserved() {
        let e = check_chunk(&chunk(&[(10, 4), (i32::MAX, 3)])).unwrap_err();
        assert!(e.contains("2147483647 bytes uncompressed"), "{e}");
    }

    #[test]
    fn sizes_that_leave_the_chunk_or_are_negative_or_cut_short_are_refused() {
        let mut c = chunk(&[(10, 4)]);
        c.truncate(c.len() - 1);
        assert!(check_chunk(&c).unwrap_err().contains("leaves its column chunk"));
        assert!(check_chunk(&chunk(&[(-5, 0)])).unwrap_err().contains("negative"));
        let h = header(10, 4);
        assert!(check_chunk(&h[..h.len() - 3]).unwrap_err().contains("cut short"));
    }

    #[test]
    fn a_binary_declaring_gigabytes_is_skipped_without_reserving_it() {
        // field 4 (crc) as a binary of 2^32 bytes: refused as cut short, nothing allocated for it.
        let mut h = vec![0x48, 0x80, 0x80, 0x80, 0x80, 0x10];
        h.extend(header(10, 0));
        assert!(check_chunk(&h).unwrap_err().contains("cut short"));
    }

    #[test]
    fn nesting_past_the_limit_is_refused() {
        let mut h = vec![0x1c; MAX_DEPTH + 3];
        h.extend(vec![0; MAX_DEPTH + 3]);
        assert!(check_chunk(&h).unwrap_err().contains("nested too deep"));
    }
}
