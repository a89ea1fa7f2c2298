//! Particle sets and their readers: PLY (ascii, binary little and big endian) and delimited
//! text with a header (CSV, TSV, whitespace).
//!
//! Readers stream: a `BufRead` is parsed record by record straight into the output vectors,
//! so stdin works and memory is the particle set itself. Positions are kept in f64 because
//! scenes come with large offsets (1e6 away from the origin an f32 keeps only ~0.06 units);
//! the estimator rebases them onto its grid before going to f32.
//!
//! Skipped, not fatal: rows with a non-finite position or mass (counted in [`ReadReport`]).
//! Fatal, with the place named: a negative mass, a malformed number, a header that promises
//! more vertices than the file holds, a file without x, y or z.
//!
//! Attributes (design.md section 8): the readers also read the per-particle attributes asked
//! for by name ([`read_particles_with`]), by one naming rule for PLY properties and text
//! columns ([`available_attributes`], [`find_attribute`]): a column `NAME` is a float
//! attribute `NAME`; three columns `Px Py Pz`, `P_x P_y P_z`, `P.x P.y P.z` or
//! `P[0] P[1] P[2]` (any prefix P but the empty one, which is the position) are a vec3
//! attribute `P` (so `vx vy vz` is `v`, `nx ny nz` is `n`, `Cd_x Cd_y Cd_z` is `Cd`). A
//! column of the very name asked for wins over a triple. A name not found is looked up under
//! its aliases ([`attribute_aliases`]: `v`, `vel`, `velocity`; `Cd`, `color`, `colour`).
//! Attribute values are kept as they are, non-finite ones included: the estimator leaves
//! those particles out of that attribute's grid and counts them.

use std::collections::BTreeMap;
use std::io::{BufRead, BufReader, BufWriter, Read, Write};
use std::path::Path;

use glam::{DVec3, Vec3};

/// One per-particle attribute, one value per position.
#[derive(Clone, Debug, PartialEq)]
pub enum Attribute {
    Float(Vec<f32>),
    Vec3(Vec<Vec3>),
}

impl Attribute {
    pub fn len(&self) -> usize {
        match self {
            Attribute::Float(v) => v.len(),
            Attribute::Vec3(v) => v.len(),
        }
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Components per value: 1 or 3.
    pub fn width(&self) -> usize {
        match self {
            Attribute::Float(_) => 1,
            Attribute::Vec3(_) => 3,
        }
    }

    /// Value `i` as its components (the first `width()` entries).
    #[inline]
    pub fn get(&self, i: usize) -> [f32; 3] {
        match self {
            Attribute::Float(v) => [v[i], 0.0, 0.0],
            Attribute::Vec3(v) => v[i].to_array(),
        }
    }
}

/// Particles in world space; `masses`, when present, has one entry per position, and so has
/// each of `attributes` (by name: the name asked for, see [`read_particles_with`]).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ParticleSet {
    pub positions: Vec<DVec3>,
    pub masses: Option<Vec<f32>>,
    pub attributes: BTreeMap<String, Attribute>,
}

impl ParticleSet {
    pub fn new(positions: Vec<DVec3>) -> ParticleSet {
        ParticleSet { positions, masses: None, attributes: BTreeMap::new() }
    }

    pub fn with_attribute(mut self, name: &str, values: Attribute) -> ParticleSet {
        self.attributes.insert(name.to_string(), values);
        self
    }

    pub fn len(&self) -> usize {
        self.positions.len()
    }

    pub fn is_empty(&self) -> bool {
        self.positions.is_empty()
    }

    /// Mass of particle `i`, `default` when the set carries no masses.
    #[inline]
    pub fn mass(&self, i: usize, default: f32) -> f32 {
        self.masses.as_ref().map_or(default, |m| m[i])
    }

    /// Total mass, `default` per particle when the set carries no masses.
    pub fn total_mass(&self, default: f32) -> f64 {
        match &self.masses {
            Some(m) => m.iter().map(|&m| m as f64).sum(),
            None => default as f64 * self.len() as f64,
        }
    }
}

/// What a reader found besides the particles, for the tool's warnings and `-v`.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ReadReport {
    pub format: Option<Format>,
    /// Records read, kept or not.
    pub rows: u64,
    /// Records skipped for a non-finite position or mass.
    pub skipped_nonfinite: u64,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Format {
    Ply,
    /// Delimited text with a header row; the delimiter (`,` `;` tab or whitespace) is detected
    /// from the header.
    Csv,
    /// Tab-separated text with a header row.
    Tsv,
}

impl Format {
    /// The format a file name implies: .ply, .csv, .tsv, and .txt/.xyz as detected text.
    pub fn from_path(path: &Path) -> Option<Format> {
        let ext = path.extension()?.to_str()?.to_ascii_lowercase();
        match ext.as_str() {
            "ply" => Some(Format::Ply),
            "csv" | "txt" | "xyz" => Some(Format::Csv),
            "tsv" | "tab" => Some(Format::Tsv),
            _ => None,
        }
    }

    /// Parses a `--format` value.
    pub fn from_name(name: &str) -> Option<Format> {
        match name.to_ascii_lowercase().as_str() {
            "ply" => Some(Format::Ply),
            "csv" | "txt" | "text" => Some(Format::Csv),
            "tsv" => Some(Format::Tsv),
            _ => None,
        }
    }
}

#[derive(Debug, thiserror::Error)]
pub enum ReadError {
    #[error("read failed: {0}")]
    Io(#[from] std::io::Error),
    #[error("unknown particle format {0:?} (expected ply, csv or tsv)")]
    UnknownFormat(String),
    #[error("not a PLY file: {0}")]
    NotPly(String),
    #[error("PLY header line {line}: {message}")]
    PlyHeader { line: usize, message: String },
    #[error("PLY header promises {expected} vertices but the file holds only {found}")]
    Truncated { expected: u64, found: u64 },
    #[error("no `{0}` column or property")]
    MissingCoordinate(&'static str),
    #[error("{place}: cannot read {what} from {text:?}")]
    BadNumber { place: String, what: String, text: String },
    #[error("{place}: expected {expected} fields, found {found}")]
    FieldCount { place: String, expected: usize, found: usize },
    #[error("{place}: negative mass {mass}")]
    NegativeMass { place: String, mass: f64 },
    #[error("empty input: no header line")]
    NoHeader,
    #[error("no particle attribute `{name}` (available: {available})")]
    UnknownAttribute { name: String, available: String },
    #[error("attribute `{0}` is a PLY list property, not a float or a vec3")]
    ListAttribute(String),
}

/// Other names an attribute is found under when its own is not in the file: velocity
/// (`v` Houdini's, `vel` Blender's and Mantaflow's, `velocity`) and colour (`Cd` Houdini's,
/// `color`, `colour`). Every other name has none.
pub fn attribute_aliases(name: &str) -> &'static [&'static str] {
    const VELOCITY: &[&str] = &["v", "vel", "velocity"];
    const COLOUR: &[&str] = &["Cd", "color", "colour"];
    [VELOCITY, COLOUR].into_iter().find(|set| set.contains(&name)).unwrap_or(&[])
}

/// Which of `available` attribute `name` reads: `name` itself, else the first of its
/// [`attribute_aliases`] that is available.
pub fn find_attribute<'a>(available: &[&'a str], name: &str) -> Option<&'a str> {
    std::iter::once(name)
        .chain(attribute_aliases(name).iter().copied())
        .find_map(|want| available.iter().copied().find(|&a| a == want))
}

/// The attributes a header's column (or property) names offer, by the naming rule in the
/// module docs: (name, the columns of its components), floats then vec3 triples, each in
/// column order. x, y and z are the position and offer nothing.
pub fn available_attributes(names: &[String]) -> Vec<(String, Vec<usize>)> {
    let is_position = |n: &str| ["x", "y", "z"].iter().any(|c| n.eq_ignore_ascii_case(c));
    let mut out: Vec<(String, Vec<usize>)> =
        names.iter().enumerate().filter(|(_, n)| !is_position(n)).map(|(i, n)| (n.clone(), vec![i])).collect();
    // Component suffixes: x y z, _x _y _z, .x .y .z (either case), [0] [1] [2].
    let triple = |n: &str| -> Option<(String, usize)> {
        if let Some(stem) = n.strip_suffix(']') {
            let (prefix, k) = stem.rsplit_once('[')?;
            let k = ["0", "1", "2"].iter().position(|&d| d == k)?;
            return (!prefix.is_empty()).then(|| (prefix.to_string(), k));
        }
        let last = n.chars().last()?;
        let k = ['x', 'y', 'z'].iter().position(|&c| c == last.to_ascii_lowercase())?;
        let prefix = &n[..n.len() - 1];
        let prefix = prefix.strip_suffix(['_', '.']).unwrap_or(prefix);
        (!prefix.is_empty()).then(|| (prefix.to_string(), k))
    };
    let mut groups: Vec<(String, [Option<usize>; 3])> = Vec::new();
    for (i, n) in names.iter().enumerate() {
        if let Some((prefix, k)) = triple(n) {
            match groups.iter_mut().find(|(p, _)| *p == prefix) {
                Some((_, cols)) => cols[k] = cols[k].or(Some(i)),
                None => {
                    let mut cols = [None; 3];
                    cols[k] = Some(i);
                    groups.push((prefix, cols));
                }
            }
        }
    }
    for (prefix, cols) in groups {
        if let [Some(a), Some(b), Some(c)] = cols {
            if !out.iter().any(|(n, _)| *n == prefix) {
                out.push((prefix, vec![a, b, c]));
            }
        }
    }
    out
}

/// The columns of each requested attribute, or the error that lists what is available.
fn resolve_attributes(names: &[String], requested: &[String]) -> Result<Vec<(String, Vec<usize>)>, ReadError> {
    let available = available_attributes(names);
    let list: Vec<&str> = available.iter().map(|(n, _)| n.as_str()).collect();
    requested
        .iter()
        .map(|want| {
            let found = find_attribute(&list, want).ok_or_else(|| ReadError::UnknownAttribute {
                name: want.clone(),
                available: if list.is_empty() { "none".into() } else { list.join(", ") },
            })?;
            let cols = available.iter().find(|(n, _)| n == found).expect("listed").1.clone();
            Ok((want.clone(), cols))
        })
        .collect()
}

/// Reads particles from any reader (a file, stdin) in the given format.
pub fn read_particles<R: Read>(reader: R, format: Format) -> Result<(ParticleSet, ReadReport), ReadError> {
    read_particles_with(reader, format, &[])
}

/// Reads particles and the attributes named in `attributes` (the naming rule and aliases of
/// the module docs), each stored under the name asked for; an attribute the file lacks is an
/// error listing the ones it has.
pub fn read_particles_with<R: Read>(reader: R, format: Format, attributes: &[String]) -> Result<(ParticleSet, ReadReport), ReadError> {
    let mut reader = BufReader::with_capacity(1 << 16, reader);
    let mut sink = Sink { requested: attributes.to_vec(), ..Sink::default() };
    match format {
        Format::Ply => read_ply(&mut reader, &mut sink)?,
        Format::Csv => read_delimited(&mut reader, None, &mut sink)?,
        Format::Tsv => read_delimited(&mut reader, Some(Delimiter::Byte(b'\t')), &mut sink)?,
    }
    sink.report.format = Some(format);
    Ok(sink.finish())
}

/// Reads a particle file; the format comes from `format` or else the file's extension.
pub fn read_path(path: &Path, format: Option<Format>) -> Result<(ParticleSet, ReadReport), ReadError> {
    let format = format
        .or_else(|| Format::from_path(path))
        .ok_or_else(|| ReadError::UnknownFormat(path.display().to_string()))?;
    read_particles(std::fs::File::open(path)?, format)
}

/// Writes a binary little-endian PLY: `double x y z`, plus `float mass` when the set has
/// masses. Positions stay f64, so a round trip through [`read_particles`] is exact.
pub fn write_ply<W: Write>(writer: W, particles: &ParticleSet) -> std::io::Result<()> {
    let mut w = BufWriter::new(writer);
    writeln!(w, "ply\nformat binary_little_endian 1.0\nelement vertex {}", particles.len())?;
    writeln!(w, "property double x\nproperty double y\nproperty double z")?;
    if particles.masses.is_some() {
        writeln!(w, "property float mass")?;
    }
    writeln!(w, "end_header")?;
    for (i, p) in particles.positions.iter().enumerate() {
        for c in p.to_array() {
            w.write_all(&c.to_le_bytes())?;
        }
        if let Some(m) = &particles.masses {
            w.write_all(&m[i].to_le_bytes())?;
        }
    }
    w.flush()
}

/// Collects records into the output vectors as they are parsed, applying the skip/error rules
/// in one place for every format.
#[derive(Default)]
struct Sink {
    positions: Vec<DVec3>,
    masses: Option<Vec<f32>>,
    /// The attributes asked for, and per attribute its components' values, flat.
    requested: Vec<String>,
    attributes: Vec<Vec<f32>>,
    /// Components of each requested attribute (1 or 3), set from the header.
    widths: Vec<usize>,
    report: ReadReport,
}

impl Sink {
    fn reserve(&mut self, n: usize, with_mass: bool) {
        // Cap the up-front reservation: a header's count is a promise, not a fact.
        let n = n.min(1 << 24);
        self.positions.reserve(n);
        if with_mass {
            self.masses.get_or_insert_with(Vec::new).reserve(n);
        }
    }

    /// The header's columns are known: one value buffer per requested attribute.
    fn begin(&mut self, columns: &Columns) {
        self.widths = columns.attrs.iter().map(|(_, c)| c.len()).collect();
        self.attributes = vec![Vec::new(); columns.attrs.len()];
    }

    /// One record's values by the columns found.
    fn push_record(&mut self, columns: &Columns, values: &[f64], place: impl FnOnce() -> String) -> Result<(), ReadError> {
        let (p, m) = columns.record(values);
        if self.push(p, m, place)? {
            for ((_, cols), out) in columns.attrs.iter().zip(&mut self.attributes) {
                out.extend(cols.iter().map(|&c| values[c] as f32));
            }
        }
        Ok(())
    }

    /// Keeps the particle unless it is skipped; returns whether it was kept.
    fn push(&mut self, p: DVec3, mass: Option<f64>, place: impl FnOnce() -> String) -> Result<bool, ReadError> {
        self.report.rows += 1;
        // Masses are kept as f32: one finite in f64 but beyond f32's range (1e39) would be
        // stored as infinity, so it counts as non-finite too (found by fuzzing).
        if !p.is_finite() || mass.is_some_and(|m| !(m as f32).is_finite()) {
            self.report.skipped_nonfinite += 1;
            return Ok(false);
        }
        if let Some(m) = mass {
            if m < 0.0 {
                return Err(ReadError::NegativeMass { place: place(), mass: m });
            }
            self.masses.get_or_insert_with(Vec::new).push(m as f32);
        }
        self.positions.push(p);
        Ok(true)
    }

    fn finish(self) -> (ParticleSet, ReadReport) {
        let attributes = self
            .requested
            .into_iter()
            .zip(self.attributes)
            .zip(self.widths)
            .map(|((name, flat), width)| {
                let values = match width {
                    3 => Attribute::Vec3(flat.chunks_exact(3).map(Vec3::from_slice).collect()),
                    _ => Attribute::Float(flat),
                };
                (name, values)
            })
            .collect();
        (ParticleSet { positions: self.positions, masses: self.masses, attributes }, self.report)
    }
}

/// Which fields of a record hold x, y, z, the optional mass and the requested attributes.
struct Columns {
    xyz: [usize; 3],
    mass: Option<usize>,
    /// Per requested attribute, its components' fields.
    attrs: Vec<(String, Vec<usize>)>,
}

impl Columns {
    fn find(names: &[String], requested: &[String]) -> Result<Columns, ReadError> {
        let find = |want: &[&str]| names.iter().position(|n| want.iter().any(|w| n.eq_ignore_ascii_case(w)));
        let coord = |name: &'static str| find(&[name]).ok_or(ReadError::MissingCoordinate(name));
        Ok(Columns {
            xyz: [coord("x")?, coord("y")?, coord("z")?],
            mass: find(&["mass", "m"]),
            attrs: resolve_attributes(names, requested)?,
        })
    }

    /// Every field a record's parse needs.
    fn used(&self) -> impl Iterator<Item = usize> + '_ {
        self.xyz.iter().chain(self.mass.iter()).copied().chain(self.attrs.iter().flat_map(|(_, c)| c.iter().copied()))
    }

    fn record(&self, values: &[f64]) -> (DVec3, Option<f64>) {
        let [x, y, z] = self.xyz;
        (DVec3::new(values[x], values[y], values[z]), self.mass.map(|m| values[m]))
    }
}

fn parse_number(text: &str, place: impl FnOnce() -> String, what: impl FnOnce() -> String) -> Result<f64, ReadError> {
    text.parse::<f64>()
        .map_err(|_| ReadError::BadNumber { place: place(), what: what(), text: text.to_string() })
}

// ---------------------------------------------------------------------------------------------
// Delimited text

#[derive(Clone, Copy, PartialEq)]
enum Delimiter {
    Byte(u8),
    Whitespace,
}

impl Delimiter {
    fn detect(header: &str) -> Delimiter {
        [b',', b'\t', b';']
            .into_iter()
            .find(|&b| header.as_bytes().contains(&b))
            .map_or(Delimiter::Whitespace, Delimiter::Byte)
    }

    /// The fields of a line, trimmed of surrounding whitespace.
    fn split(self, line: &str) -> Fields<'_> {
        match self {
            Delimiter::Byte(b) => Fields::Byte(line.split(b as char)),
            Delimiter::Whitespace => Fields::Whitespace(line.split_ascii_whitespace()),
        }
    }
}

/// Iterator over a line's fields for either kind of delimiter, without allocating per line.
enum Fields<'a> {
    Byte(std::str::Split<'a, char>),
    Whitespace(std::str::SplitAsciiWhitespace<'a>),
}

impl<'a> Iterator for Fields<'a> {
    type Item = &'a str;

    fn next(&mut self) -> Option<&'a str> {
        match self {
            Fields::Byte(s) => s.next().map(str::trim),
            Fields::Whitespace(s) => s.next(),
        }
    }
}

/// True for lines that carry no record: blank, or a `#` comment.
fn is_blank(line: &str) -> bool {
    let t = line.trim();
    t.is_empty() || t.starts_with('#')
}

fn read_delimited<R: BufRead>(reader: &mut R, delimiter: Option<Delimiter>, sink: &mut Sink) -> Result<(), ReadError> {
    let mut line = String::new();
    let mut line_no = 0usize;
    // Header: the first line that is not blank or a comment.
    loop {
        line.clear();
        if reader.read_line(&mut line)? == 0 {
            return Err(ReadError::NoHeader);
        }
        line_no += 1;
        if !is_blank(&line) {
            break;
        }
    }
    let delimiter = delimiter.unwrap_or_else(|| Delimiter::detect(&line));
    let names: Vec<String> =
        delimiter.split(line.trim_end_matches(['\r', '\n'])).map(|f| f.trim_matches('"').to_string()).collect();
    let columns = Columns::find(&names, &sink.requested)?;
    sink.begin(&columns);
    sink.reserve(0, columns.mass.is_some());
    // Parse only the columns we use: other columns may hold text (ids, names).
    let mut wanted = vec![false; names.len()];
    for c in columns.used() {
        wanted[c] = true;
    }

    let mut values = vec![0.0f64; names.len()];
    loop {
        line.clear();
        if reader.read_line(&mut line)? == 0 {
            return Ok(());
        }
        line_no += 1;
        if is_blank(&line) {
            continue;
        }
        let place = || format!("line {line_no}");
        let mut found = 0;
        for (c, field) in delimiter.split(line.trim_end_matches(['\r', '\n'])).enumerate() {
            found = c + 1;
            if wanted.get(c) == Some(&true) {
                let text = field.trim_matches('"');
                values[c] = parse_number(text, place, || format!("column `{}`", names[c]))?;
            }
        }
        if found < names.len() {
            return Err(ReadError::FieldCount { place: place(), expected: names.len(), found });
        }
        sink.push_record(&columns, &values, place)?;
    }
}

// ---------------------------------------------------------------------------------------------
// PLY

#[derive(Clone, Copy, Debug, PartialEq)]
enum Scalar {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
}

impl Scalar {
    fn parse(name: &str) -> Option<Scalar> {
        Some(match name {
            "char" | "int8" => Scalar::I8,
            "uchar" | "uint8" => Scalar::U8,
            "short" | "int16" => Scalar::I16,
            "ushort" | "uint16" => Scalar::U16,
            "int" | "int32" => Scalar::I32,
            "uint" | "uint32" => Scalar::U32,
            "float" | "float32" => Scalar::F32,
            "double" | "float64" => Scalar::F64,
            _ => return None,
        })
    }

    fn size(self) -> usize {
        match self {
            Scalar::I8 | Scalar::U8 => 1,
            Scalar::I16 | Scalar::U16 => 2,
            Scalar::I32 | Scalar::U32 | Scalar::F32 => 4,
            Scalar::F64 => 8,
        }
    }

    /// Decodes one value from its bytes in the file's byte order.
    fn decode(self, b: &[u8], big_endian: bool) -> f64 {
        macro_rules! get {
            ($t:ty, $n:expr) => {{
                let a: [u8; $n] = b[..$n].try_into().unwrap();
                (if big_endian { <$t>::from_be_bytes(a) } else { <$t>::from_le_bytes(a) }) as f64
            }};
        }
        match self {
            Scalar::I8 => b[0] as i8 as f64,
            Scalar::U8 => b[0] as f64,
            Scalar::I16 => get!(i16, 2),
            Scalar::U16 => get!(u16, 2),
            Scalar::I32 => get!(i32, 4),
            Scalar::U32 => get!(u32, 4),
            Scalar::F32 => get!(f32, 4),
            Scalar::F64 => get!(f64, 8),
        }
    }
}

#[derive(Debug)]
enum Property {
    Scalar(Scalar),
    /// A list: the count's type, then the items' type.
    List(Scalar, Scalar),
}

#[derive(Debug)]
struct Element {
    name: String,
    count: u64,
    names: Vec<String>,
    props: Vec<Property>,
}

#[derive(Clone, Copy, PartialEq)]
enum Encoding {
    Ascii,
    Binary { big_endian: bool },
}

fn read_ply<R: BufRead>(reader: &mut R, sink: &mut Sink) -> Result<(), ReadError> {
    let (encoding, elements) = read_ply_header(reader)?;
    let mut line_no = 0usize; // counts body lines, for ascii error places
    for element in &elements {
        if element.name == "vertex" {
            return read_ply_vertices(reader, encoding, element, sink, &mut line_no);
        }
        skip_ply_element(reader, encoding, element, &mut line_no)?;
    }
    Err(ReadError::MissingCoordinate("x"))
}

fn read_ply_header<R: BufRead>(reader: &mut R) -> Result<(Encoding, Vec<Element>), ReadError> {
    let mut line = String::new();
    let mut line_no = 0usize;
    let mut next_line = |line: &mut String| -> Result<usize, ReadError> {
        line.clear();
        if reader.read_line(line)? == 0 {
            return Err(ReadError::NotPly("header ends before end_header".into()));
        }
        line_no += 1;
        Ok(line_no)
    };
    next_line(&mut line)?;
    if line.trim_end() != "ply" {
        return Err(ReadError::NotPly("first line is not `ply`".into()));
    }
    let mut encoding = None;
    let mut elements: Vec<Element> = Vec::new();
    loop {
        let n = next_line(&mut line)?;
        let err = |message: String| ReadError::PlyHeader { line: n, message };
        let words: Vec<&str> = line.split_ascii_whitespace().collect();
        match words.as_slice() {
            ["end_header"] => break,
            ["comment", ..] | ["obj_info", ..] | [] => {}
            ["format", kind, _version] => {
                encoding = Some(match *kind {
                    "ascii" => Encoding::Ascii,
                    "binary_little_endian" => Encoding::Binary { big_endian: false },
                    "binary_big_endian" => Encoding::Binary { big_endian: true },
                    other => return Err(err(format!("unknown format `{other}`"))),
                });
            }
            ["element", name, count] => {
                let count = count.parse().map_err(|_| err(format!("bad element count `{count}`")))?;
                elements.push(Element { name: name.to_string(), count, names: Vec::new(), props: Vec::new() });
            }
            ["property", "list", count_ty, item_ty, name] => {
                let ty = |t: &str| Scalar::parse(t).ok_or_else(|| err(format!("unknown type `{t}`")));
                let prop = Property::List(ty(count_ty)?, ty(item_ty)?);
                let element = elements.last_mut().ok_or_else(|| err("property before any element".into()))?;
                element.props.push(prop);
                element.names.push(name.to_string());
            }
            ["property", ty, name] => {
                let prop = Property::Scalar(Scalar::parse(ty).ok_or_else(|| err(format!("unknown type `{ty}`")))?);
                let element = elements.last_mut().ok_or_else(|| err("property before any element".into()))?;
                element.props.push(prop);
                element.names.push(name.to_string());
            }
            _ => return Err(err(format!("cannot read `{}`", line.trim_end()))),
        }
    }
    let encoding = encoding.ok_or_else(|| ReadError::NotPly("no format line".into()))?;
    Ok((encoding, elements))
}

/// Reads one binary value, mapping a short read to `None` (the caller knows what was promised).
fn read_binary<R: BufRead>(reader: &mut R, ty: Scalar, big_endian: bool) -> Result<Option<f64>, ReadError> {
    let mut buf = [0u8; 8];
    match reader.read_exact(&mut buf[..ty.size()]) {
        Ok(()) => Ok(Some(ty.decode(&buf, big_endian))),
        Err(e) if e.kind() == std::io::ErrorKind::UnexpectedEof => Ok(None),
        Err(e) => Err(e.into()),
    }
}

/// Reads one record of `element` into `values` (scalars only; list properties are consumed
/// and left as 0). Returns false at end of input before the record starts or completes.
fn read_ply_record<R: BufRead>(
    reader: &mut R,
    encoding: Encoding,
    element: &Element,
    values: &mut [f64],
    line: &mut String,
    line_no: &mut usize,
) -> Result<bool, ReadError> {
    match encoding {
        Encoding::Binary { big_endian } => {
            for (prop, value) in element.props.iter().zip(values.iter_mut()) {
                match *prop {
                    Property::Scalar(ty) => match read_binary(reader, ty, big_endian)? {
                        Some(v) => *value = v,
                        None => return Ok(false),
                    },
                    Property::List(count_ty, item_ty) => {
                        let Some(count) = read_binary(reader, count_ty, big_endian)? else { return Ok(false) };
                        let bytes = count as u64 * item_ty.size() as u64;
                        if std::io::copy(&mut reader.by_ref().take(bytes), &mut std::io::sink())? < bytes {
                            return Ok(false);
                        }
                    }
                }
            }
            Ok(true)
        }
        Encoding::Ascii => {
            // Skip blank lines; a record is one line of tokens.
            loop {
                line.clear();
                if reader.read_line(line)? == 0 {
                    return Ok(false);
                }
                *line_no += 1;
                if !line.trim().is_empty() {
                    break;
                }
            }
            let place = || format!("PLY body line {}", *line_no);
            let mut tokens = line.split_ascii_whitespace();
            let mut next = |what: &str| {
                let t = tokens.next().ok_or_else(|| ReadError::BadNumber {
                    place: place(),
                    what: format!("property `{what}`"),
                    text: String::new(),
                })?;
                parse_number(t, place, || format!("property `{what}`"))
            };
            for ((prop, name), value) in element.props.iter().zip(&element.names).zip(values.iter_mut()) {
                match prop {
                    Property::Scalar(_) => *value = next(name)?,
                    Property::List(..) => {
                        let count = next(name)?;
                        for _ in 0..count as u64 {
                            next(name)?;
                        }
                    }
                }
            }
            Ok(true)
        }
    }
}

fn skip_ply_element<R: BufRead>(
    reader: &mut R,
    encoding: Encoding,
    element: &Element,
    line_no: &mut usize,
) -> Result<(), ReadError> {
    // An element without properties holds no data: its records take no bytes, so counting
    // through a header's 2^64 of them would never end (found by fuzzing).
    if element.props.is_empty() {
        return Ok(());
    }
    let mut values = vec![0.0; element.props.len()];
    let mut line = String::new();
    for i in 0..element.count {
        if !read_ply_record(reader, encoding, element, &mut values, &mut line, line_no)? {
            return Err(ReadError::NotPly(format!(
                "header promises {} `{}` elements but the file holds only {i}",
                element.count, element.name
            )));
        }
    }
    Ok(())
}

fn read_ply_vertices<R: BufRead>(
    reader: &mut R,
    encoding: Encoding,
    element: &Element,
    sink: &mut Sink,
    line_no: &mut usize,
) -> Result<(), ReadError> {
    let columns = Columns::find(&element.names, &sink.requested)?;
    if columns.xyz.iter().chain(columns.mass.iter()).any(|&c| matches!(element.props[c], Property::List(..))) {
        return Err(ReadError::NotPly("vertex x, y, z or mass is a list property".into()));
    }
    if let Some((name, _)) = columns.attrs.iter().find(|(_, cols)| cols.iter().any(|&c| matches!(element.props[c], Property::List(..)))) {
        return Err(ReadError::ListAttribute(name.clone()));
    }
    sink.begin(&columns);
    sink.reserve(element.count as usize, columns.mass.is_some());
    let mut values = vec![0.0; element.props.len()];

    // Binary records without lists have a fixed size: read each with one copy from the buffer.
    let fixed: Option<Vec<(Scalar, usize)>> = element
        .props
        .iter()
        .scan(0usize, |offset, p| {
            Some(match *p {
                Property::Scalar(ty) => {
                    let at = *offset;
                    *offset += ty.size();
                    Some((ty, at))
                }
                Property::List(..) => None,
            })
        })
        .collect();
    if let (Encoding::Binary { big_endian }, Some(layout)) = (encoding, fixed) {
        let size: usize = layout.iter().map(|(ty, _)| ty.size()).sum();
        let mut record = vec![0u8; size];
        for i in 0..element.count {
            match reader.read_exact(&mut record) {
                Ok(()) => {}
                Err(e) if e.kind() == std::io::ErrorKind::UnexpectedEof => {
                    return Err(ReadError::Truncated { expected: element.count, found: i });
                }
                Err(e) => return Err(e.into()),
            }
            for (value, &(ty, at)) in values.iter_mut().zip(&layout) {
                *value = ty.decode(&record[at..], big_endian);
            }
            sink.push_record(&columns, &values, || format!("vertex {i}"))?;
        }
        return Ok(());
    }

    let mut line = String::new();
    for i in 0..element.count {
        if !read_ply_record(reader, encoding, element, &mut values, &mut line, line_no)? {
            return Err(ReadError::Truncated { expected: element.count, found: i });
        }
        sink.push_record(&columns, &values, || format!("vertex {i}"))?;
    }
    Ok(())
}
