//! A parquet file read whole through arrow, and its columns as plain vectors with the checks every caller needs
//! (present, the expected type, no nulls, the expected number of values per row).

use std::path::{Path, PathBuf};

use arrow_array::cast::AsArray;
use arrow_array::types::{Float32Type, Float64Type, Int64Type};
use arrow_array::{Array, ArrayRef, RecordBatch};
use arrow_schema::DataType;
use parquet::arrow::arrow_reader::ParquetRecordBatchReaderBuilder;

use crate::LeRobotError;

pub struct Table {
    pub path: PathBuf,
    batches: Vec<RecordBatch>,
}

impl Table {
    /// Reads every row of `path`, only the named root columns when `columns` is given (images stored in the data
    /// file are never read when only vectors are asked for).
    pub fn read(path: &Path, columns: Option<&[&str]>) -> Result<Self, LeRobotError> {
        // Read whole, then decoded from memory: every row is read anyway, and the reader's many small reads of a
        // damaged file's headers cost a syscall each from a `File` (seconds for a 17 kB file the fuzzer made).
        let bytes = std::fs::read(path).map_err(|error| LeRobotError::Read { path: path.to_owned(), error })?;
        Self::from_bytes(path, bytes, columns)
    }

    /// [`Table::read`] of a parquet file's bytes (`path` names it in errors).
    pub fn from_bytes(path: &Path, bytes: Vec<u8>, columns: Option<&[&str]>) -> Result<Self, LeRobotError> {
        Self::decode(path, bytes::Bytes::from(bytes), columns)
    }

    fn decode(path: &Path, r: bytes::Bytes, columns: Option<&[&str]>) -> Result<Self, LeRobotError> {
        crate::contain::decode(|| Self::decode_uncontained(path, r, columns))
            .unwrap_or_else(|panic| Err(LeRobotError::parquet(path, format!("the parquet reader failed: {panic}"))))
    }

    fn decode_uncontained(path: &Path, r: bytes::Bytes, columns: Option<&[&str]>) -> Result<Self, LeRobotError> {
        let builder =
            ParquetRecordBatchReaderBuilder::try_new(r.clone()).map_err(|e| LeRobotError::parquet(path, e))?;
        // Before the reader reserves what a page header declares (up to 2 GiB each).
        crate::page_sizes::check(&r, builder.metadata()).map_err(|e| LeRobotError::parquet(path, e))?;
        let builder = match columns {
            None => builder,
            Some(names) => {
                let schema = builder.schema().clone();
                let mut roots = Vec::with_capacity(names.len());
                for name in names {
                    let i = schema.index_of(name).map_err(|_| LeRobotError::Column {
                        path: path.to_owned(),
                        column: (*name).to_owned(),
                        problem: format!(
                            "missing (the file has: {})",
                            schema.fields().iter().map(|f| f.name().as_str()).collect::<Vec<_>>().join(", ")
                        ),
                    })?;
                    roots.push(i);
                }
                let mask = parquet::arrow::ProjectionMask::roots(builder.parquet_schema(), roots);
                builder.with_projection(mask)
            }
        };
        let reader = builder.build().map_err(|e| LeRobotError::parquet(path, e))?;
        let batches = reader.collect::<Result<Vec<_>, _>>().map_err(|e| LeRobotError::parquet(path, e))?;
        Ok(Self { path: path.to_owned(), batches })
    }

    /// The file's record batches, as arrow read them.
    pub fn batches(&self) -> &[RecordBatch] {
        &self.batches
    }

    pub fn rows(&self) -> usize {
        self.batches.iter().map(RecordBatch::num_rows).sum()
    }

    fn err(&self, column: &str, problem: impl Into<String>) -> LeRobotError {
        LeRobotError::Column { path: self.path.clone(), column: column.to_owned(), problem: problem.into() }
    }

    /// The column's pieces, one per batch, with nulls refused.
    fn pieces(&self, column: &str) -> Result<Vec<ArrayRef>, LeRobotError> {
        let mut out = Vec::with_capacity(self.batches.len());
        for b in &self.batches {
            let a = b.column_by_name(column).ok_or_else(|| self.err(column, "missing"))?;
            if a.null_count() > 0 {
                return Err(self.err(column, format!("{} null values", a.null_count())));
            }
            out.push(a.clone());
        }
        Ok(out)
    }

    pub fn i64s(&self, column: &str) -> Result<Vec<i64>, LeRobotError> {
        let mut out = Vec::with_capacity(self.rows());
        for a in self.pieces(column)? {
            let a = a
                .as_primitive_opt::<Int64Type>()
                .ok_or_else(|| self.err(column, format!("{}, not int64", a.data_type())))?;
            out.extend(a.values().iter().copied());
        }
        Ok(out)
    }

    /// A float column (float32 or float64) as f64.
    pub fn f64s(&self, column: &str) -> Result<Vec<f64>, LeRobotError> {
        let mut out = Vec::with_capacity(self.rows());
        for a in self.pieces(column)? {
            match a.data_type() {
                DataType::Float64 => out.extend(a.as_primitive::<Float64Type>().values().iter().copied()),
                DataType::Float32 => out.extend(a.as_primitive::<Float32Type>().values().iter().map(|&v| f64::from(v))),
                t => return Err(self.err(column, format!("{t}, not a float"))),
            }
        }
        Ok(out)
    }

    /// A vector feature: each row a list of exactly `len` float32 values (LeRobot writes fixed-size lists; plain
    /// lists are read too), rows concatenated.
    pub fn vectors(&self, column: &str, len: usize) -> Result<Vec<f32>, LeRobotError> {
        // Grown with the values found, not sized by `len` (the metadata's word, checked row by row below).
        let mut out = Vec::new();
        for a in self.pieces(column)? {
            let (values, offsets): (ArrayRef, Vec<usize>) = match a.data_type() {
                DataType::FixedSizeList(_, n) => {
                    let l = a.as_fixed_size_list();
                    let n = *n as usize;
                    (l.values().slice(l.offset() * n, l.len() * n), (0..=l.len()).map(|i| i * n).collect())
                }
                DataType::List(_) => {
                    let l = a.as_list::<i32>();
                    let first = l.value_offsets()[0] as usize;
                    let offsets = l.value_offsets().iter().map(|&o| o as usize - first).collect();
                    let end = *l.value_offsets().last().unwrap_or(&0) as usize;
                    (l.values().slice(first, end - first), offsets)
                }
                // A feature of shape (1,) is a plain value (as LeRobot writes it).
                DataType::Float32 if len == 1 => {
                    out.extend_from_slice(a.as_primitive::<Float32Type>().values());
                    continue;
                }
                DataType::Float64 if len == 1 => {
                    out.extend(a.as_primitive::<Float64Type>().values().iter().map(|&v| v as f32));
                    continue;
                }
                t => return Err(self.err(column, format!("{t}, not a list of floats"))),
            };
            if let Some(w) = offsets.windows(2).find(|w| w[1] - w[0] != len) {
                return Err(
                    self.err(column, format!("a row of {} values, the feature's shape says {len}", w[1] - w[0]))
                );
            }
            if values.null_count() > 0 {
                return Err(self.err(column, "null values inside a row"));
            }
            match values.data_type() {
                DataType::Float32 => out.extend_from_slice(values.as_primitive::<Float32Type>().values()),
                DataType::Float64 => {
                    out.extend(values.as_primitive::<Float64Type>().values().iter().map(|&v| v as f32))
                }
                t => return Err(self.err(column, format!("lists of {t}, not of float32"))),
            }
        }
        Ok(out)
    }

    /// A list-of-strings column (an episode's tasks).
    pub fn string_lists(&self, column: &str) -> Result<Vec<Vec<String>>, LeRobotError> {
        let mut out = Vec::with_capacity(self.rows());
        for a in self.pieces(column)? {
            let l = a.as_list_opt::<i32>().ok_or_else(|| self.err(column, format!("{}, not a list", a.data_type())))?;
            for i in 0..l.len() {
                let row = l.value(i);
                let s = row
                    .as_string_opt::<i32>()
                    .ok_or_else(|| self.err(column, format!("lists of {}, not of strings", row.data_type())))?;
                out.push((0..s.len()).map(|j| s.value(j).to_owned()).collect());
            }
        }
        Ok(out)
    }
}
