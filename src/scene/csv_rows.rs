//! Reading the rows of the CSV input files (particle files, roughness-radius files) with the
//! physical line of each row, so that errors name the line a user sees in an editor (comment
//! lines are skipped by the reader, so a row's index is not its line).

/// Every data row of `reader` with its line number; a row the reader cannot parse becomes
/// `error(line, message)`.
pub(crate) fn rows_with_lines<R: std::io::Read, E>(
    reader: &mut csv::Reader<R>,
    error: impl Fn(usize, String) -> E,
) -> Result<Vec<(usize, csv::StringRecord)>, E> {
    let mut rows = Vec::new();
    for record in reader.records() {
        let record = record.map_err(|e| {
            error(
                e.position().map_or(0, |p| p.line() as usize),
                format!("unreadable row: {e}"),
            )
        })?;
        let line = record.position().map_or(0, |p| p.line() as usize);
        rows.push((line, record));
    }
    Ok(rows)
}

/// Opens a CSV input file (fields trimmed, `#` starts a comment line) and reads its header.
pub(crate) fn open_with_header<E>(
    path: &std::path::Path,
    open_error: impl FnOnce(csv::Error) -> E,
    error: impl Fn(usize, String) -> E,
) -> Result<(csv::Reader<std::fs::File>, csv::StringRecord), E> {
    let mut reader = csv::ReaderBuilder::new()
        .trim(csv::Trim::All)
        .comment(Some(b'#'))
        .from_path(path)
        .map_err(open_error)?;
    let headers = reader
        .headers()
        .map_err(|e| error(1, format!("cannot read the header: {e}")))?
        .clone();
    Ok((reader, headers))
}
