//! Reading the rows of the CSV input files (particle files, roughness-radius files) with the
//! physical line of each row, so that errors name the line a user sees in an editor (comment
//! lines are skipped by the reader, so a row's index is not its line).
//!
//! The csv crate's own line numbers miscount around comment lines (a row right after `#` lines
//! gets the first comment's line) and CRLF endings, so the lines are counted here: the file is
//! read through [`LineStarts`], which notes where each line begins, and a row's line is the line
//! of the last byte the reader consumed for it (its terminator, or its last character at the end
//! of the file); the reader's byte offsets are exact.

use std::io::Read;

/// A reader that notes the byte offset of the start of every line after the first.
pub(crate) struct LineStarts<R> {
    inner: R,
    offset: u64,
    starts: Vec<u64>,
}

impl<R: Read> Read for LineStarts<R> {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        let n = self.inner.read(buf)?;
        for (i, &b) in buf[..n].iter().enumerate() {
            if b == b'\n' {
                self.starts.push(self.offset + i as u64 + 1);
            }
        }
        self.offset += n as u64;
        Ok(n)
    }
}

impl<R> LineStarts<R> {
    pub(crate) fn new(inner: R) -> Self {
        LineStarts {
            inner,
            offset: 0,
            starts: Vec::new(),
        }
    }

    /// The line (from 1) holding byte `byte`, among the bytes read so far.
    fn line_of(&self, byte: u64) -> usize {
        self.starts.partition_point(|&s| s <= byte) + 1
    }
}

/// Every data row of `reader` with its line number; a row the reader cannot parse becomes
/// `error(line, message)`.
pub(crate) fn rows_with_lines<R: Read, E>(
    reader: &mut csv::Reader<LineStarts<R>>,
    error: impl Fn(usize, String) -> E,
) -> Result<Vec<(usize, csv::StringRecord)>, E> {
    let mut rows = Vec::new();
    let mut record = csv::StringRecord::new();
    loop {
        match reader.read_record(&mut record) {
            Ok(false) => break,
            Ok(true) => {
                let end = reader.position().byte().saturating_sub(1);
                let line = reader.get_ref().line_of(end);
                rows.push((line, record.clone()));
            }
            Err(e) => {
                let line = match e.position() {
                    Some(p) => reader.get_ref().line_of(p.byte()),
                    None => 0,
                };
                return Err(error(line, format!("unreadable row: {e}")));
            }
        }
    }
    Ok(rows)
}

/// Opens a CSV input file (fields trimmed, `#` starts a comment line) and reads its header.
pub(crate) fn open_with_header<E>(
    path: &std::path::Path,
    open_error: impl FnOnce(csv::Error) -> E,
    error: impl Fn(usize, String) -> E,
) -> Result<(csv::Reader<LineStarts<std::fs::File>>, csv::StringRecord), E> {
    let file = std::fs::File::open(path).map_err(|e| open_error(csv::Error::from(e)))?;
    let mut reader = reader(LineStarts::new(file));
    let headers = reader
        .headers()
        .map_err(|e| error(1, format!("cannot read the header: {e}")))?
        .clone();
    Ok((reader, headers))
}

fn reader<R: Read>(input: LineStarts<R>) -> csv::Reader<LineStarts<R>> {
    csv::ReaderBuilder::new()
        .trim(csv::Trim::All)
        .comment(Some(b'#'))
        .from_reader(input)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The line of every row, as an editor numbers them.
    fn lines(text: &str) -> Vec<(usize, String)> {
        let mut r = reader(LineStarts::new(text.as_bytes()));
        r.headers().unwrap();
        rows_with_lines(&mut r, |line, m| format!("{line}: {m}"))
            .unwrap()
            .into_iter()
            .map(|(line, rec)| (line, rec.get(0).unwrap().to_string()))
            .collect()
    }

    #[test]
    fn rows_carry_their_lines_around_comments_blank_lines_and_crlf() {
        let v = |pairs: &[(usize, &str)]| -> Vec<(usize, String)> {
            pairs.iter().map(|&(l, s)| (l, s.to_string())).collect()
        };
        assert_eq!(lines("r\n1\n2\n3\n"), v(&[(2, "1"), (3, "2"), (4, "3")]));
        assert_eq!(
            lines("r\n1\n2\n# c\n3\n"),
            v(&[(2, "1"), (3, "2"), (5, "3")])
        );
        assert_eq!(
            lines("r\n1\n2\n# c\n# d\n3"),
            v(&[(2, "1"), (3, "2"), (6, "3")])
        );
        assert_eq!(lines("r\r\n1\r\n# c\r\n2\r\n"), v(&[(2, "1"), (4, "2")]));
        assert_eq!(lines("# a\nr\n# b\n1\n\n2\n"), v(&[(4, "1"), (6, "2")]));
        assert_eq!(lines("r\n1\n\n\n2"), v(&[(2, "1"), (5, "2")]));
    }
}
