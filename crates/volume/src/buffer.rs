//! A decoded array in its file's own scalar type and byte order.
//!
//! Readers hand over the bytes as they are; values are decoded on the fly when normalized
//! ([`super::Volume::from_buffer`], or the streamed `source` of [`super::load`]).

use std::fmt;
use std::str::FromStr;

/// The scalar types VTK and the Open SciVis naming use.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum ScalarType {
    /// Unsigned 8-bit.
    U8,
    /// Signed 8-bit.
    I8,
    /// Unsigned 16-bit.
    U16,
    /// Signed 16-bit.
    I16,
    /// Unsigned 32-bit.
    U32,
    /// Signed 32-bit.
    I32,
    /// Unsigned 64-bit.
    U64,
    /// Signed 64-bit.
    I64,
    /// 32-bit float.
    F32,
    /// 64-bit float.
    F64,
}

impl ScalarType {
    /// Every scalar type.
    pub const ALL: [ScalarType; 10] = [
        ScalarType::U8,
        ScalarType::I8,
        ScalarType::U16,
        ScalarType::I16,
        ScalarType::U32,
        ScalarType::I32,
        ScalarType::U64,
        ScalarType::I64,
        ScalarType::F32,
        ScalarType::F64,
    ];

    /// The smallest and largest value of an integer type (as f64, so u64::MAX reads as
    /// 2⁶⁴); `None` for floats.
    pub fn integer_range(self) -> Option<(f64, f64)> {
        self.integer_bounds().map(|(lo, hi)| (lo as f64, hi as f64))
    }

    /// The smallest and largest value of an integer type, exactly; `None` for floats.
    pub fn integer_bounds(self) -> Option<(i128, i128)> {
        Some(match self {
            ScalarType::U8 => (0, u8::MAX.into()),
            ScalarType::I8 => (i8::MIN.into(), i8::MAX.into()),
            ScalarType::U16 => (0, u16::MAX.into()),
            ScalarType::I16 => (i16::MIN.into(), i16::MAX.into()),
            ScalarType::U32 => (0, u32::MAX.into()),
            ScalarType::I32 => (i32::MIN.into(), i32::MAX.into()),
            ScalarType::U64 => (0, u64::MAX.into()),
            ScalarType::I64 => (i64::MIN.into(), i64::MAX.into()),
            ScalarType::F32 | ScalarType::F64 => return None,
        })
    }

    /// Bytes per value.
    pub fn size(self) -> usize {
        match self {
            ScalarType::U8 | ScalarType::I8 => 1,
            ScalarType::U16 | ScalarType::I16 => 2,
            ScalarType::U32 | ScalarType::I32 | ScalarType::F32 => 4,
            ScalarType::U64 | ScalarType::I64 | ScalarType::F64 => 8,
        }
    }

    /// The Open SciVis file-name spelling (`uint8`, `float32`, ...).
    pub fn scivis_name(self) -> &'static str {
        match self {
            ScalarType::U8 => "uint8",
            ScalarType::I8 => "int8",
            ScalarType::U16 => "uint16",
            ScalarType::I16 => "int16",
            ScalarType::U32 => "uint32",
            ScalarType::I32 => "int32",
            ScalarType::U64 => "uint64",
            ScalarType::I64 => "int64",
            ScalarType::F32 => "float32",
            ScalarType::F64 => "float64",
        }
    }

    /// The VTK XML `type` attribute spelling (`UInt8`, `Float32`, ...).
    pub fn vtk_xml_name(self) -> &'static str {
        match self {
            ScalarType::U8 => "UInt8",
            ScalarType::I8 => "Int8",
            ScalarType::U16 => "UInt16",
            ScalarType::I16 => "Int16",
            ScalarType::U32 => "UInt32",
            ScalarType::I32 => "Int32",
            ScalarType::U64 => "UInt64",
            ScalarType::I64 => "Int64",
            ScalarType::F32 => "Float32",
            ScalarType::F64 => "Float64",
        }
    }

    /// ParaView ImageReader's `DataScalarType` enumeration value spelling.
    pub fn paraview_name(self) -> &'static str {
        match self {
            ScalarType::U8 => "unsigned char",
            ScalarType::I8 => "char",
            ScalarType::U16 => "unsigned short",
            ScalarType::I16 => "short",
            ScalarType::U32 => "unsigned int",
            ScalarType::I32 => "int",
            ScalarType::U64 => "unsigned long long",
            ScalarType::I64 => "long long",
            ScalarType::F32 => "float",
            ScalarType::F64 => "double",
        }
    }
}

impl fmt::Display for ScalarType {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.scivis_name())
    }
}

/// A scalar type name that none of the accepted spellings match.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error(
    "unknown scalar type '{0}' (expected one of uint8, int8, uint16, int16, uint32, int32, \
     uint64, int64, float32, float64)"
)]
pub struct UnknownScalarType(
    /// The name as given.
    pub String,
);

impl FromStr for ScalarType {
    type Err = UnknownScalarType;

    /// Accepts the SciVis names (`uint8`), VTK XML names (`UInt8`) and C-ish aliases.
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let t = match s.to_ascii_lowercase().as_str() {
            "uint8" | "u8" | "uchar" | "unsigned_char" => ScalarType::U8,
            "int8" | "i8" | "char" | "signed_char" => ScalarType::I8,
            "uint16" | "u16" | "ushort" | "unsigned_short" => ScalarType::U16,
            "int16" | "i16" | "short" => ScalarType::I16,
            "uint32" | "u32" | "uint" | "unsigned_int" => ScalarType::U32,
            "int32" | "i32" | "int" => ScalarType::I32,
            "uint64" | "u64" | "unsigned_long" | "unsigned_long_long" => ScalarType::U64,
            "int64" | "i64" | "long" | "long_long" | "idtype" | "vtkidtype" => ScalarType::I64,
            "float32" | "f32" | "float" => ScalarType::F32,
            "float64" | "f64" | "double" => ScalarType::F64,
            _ => return Err(UnknownScalarType(s.to_string())),
        };
        Ok(t)
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Default)]
/// Byte order of stored values.
pub enum ByteOrder {
    #[default]
    /// Least significant byte first.
    Little,
    /// Most significant byte first.
    Big,
}

impl FromStr for ByteOrder {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s.to_ascii_lowercase().as_str() {
            "little" | "le" | "littleendian" => Ok(ByteOrder::Little),
            "big" | "be" | "bigendian" => Ok(ByteOrder::Big),
            _ => Err(format!("unknown byte order '{s}' (expected little or big)")),
        }
    }
}

/// Raw bytes of `len()` scalars of one type and byte order.
#[derive(Clone, Debug)]
pub struct TypedBuffer {
    /// How the bytes are stored.
    storage: ScalarType,
    byte_order: ByteOrder,
    bytes: Vec<u8>,
    /// The type the file declared (differs from `storage` for parsed text).
    declared: ScalarType,
}

/// A text value that the array's declared integer type cannot hold.
#[derive(Debug, thiserror::Error)]
#[error(
    "value {index} ({value}) is not an integer its declared type {type_name} holds ({lo} to {hi})"
)]
pub struct TextValueError {
    /// Position of the value in the array.
    pub index: usize,
    /// The value as read (a 64-bit integer's own text; others as short as they round-trip).
    pub value: String,
    /// The declared type's VTK XML name.
    pub type_name: &'static str,
    /// Smallest value the type holds, exactly.
    pub lo: i128,
    /// Largest value the type holds, exactly (u64::MAX, not 2⁶⁴).
    pub hi: i128,
}

impl TypedBuffer {
    /// `bytes.len()` must be a multiple of the type's size; extra bytes are an error upstream.
    pub fn new(scalar_type: ScalarType, byte_order: ByteOrder, bytes: Vec<u8>) -> Self {
        TypedBuffer {
            storage: scalar_type,
            byte_order,
            bytes,
            declared: scalar_type,
        }
    }

    /// For text formats: parsed values stored as little-endian f64.
    pub fn from_f64(values: Vec<f64>) -> Self {
        let bytes = values.iter().flat_map(|v| v.to_le_bytes()).collect();
        Self::new(ScalarType::F64, ByteOrder::Little, bytes)
    }

    /// Text values of an integer array must be integers its declared type holds (VTK would
    /// wrap 300 in a UInt8 array to 44; rendering the value 300 instead would disagree with
    /// ParaView silently). Float arrays take any value.
    pub fn check_text_values(
        values: &[f64],
        declared: ScalarType,
    ) -> Result<(), Box<TextValueError>> {
        let (Some((lo, hi)), Some((lo_exact, hi_exact))) =
            (declared.integer_range(), declared.integer_bounds())
        else {
            return Ok(());
        };
        match values
            .iter()
            .position(|&v| !(v.fract() == 0.0 && v >= lo && v <= hi))
        {
            None => Ok(()),
            Some(i) => Err(Box::new(TextValueError {
                index: i,
                value: t2tf_core::units::number(values[i]),
                type_name: declared.vtk_xml_name(),
                lo: lo_exact,
                hi: hi_exact,
            })),
        }
    }

    /// A text value of a 64-bit integer array checked exactly against its type, from its text:
    /// as f64, 2⁶⁴ and u64::MAX are the same number, so [`TypedBuffer::check_text_values`]
    /// cannot tell an overflow from the largest value. Other types and tokens that are not
    /// plain integers are left to that check.
    pub fn check_text_token(
        token: &str,
        index: usize,
        declared: ScalarType,
    ) -> Result<(), Box<TextValueError>> {
        let (lo, hi) = match declared {
            ScalarType::U64 | ScalarType::I64 => {
                declared.integer_bounds().expect("an integer type")
            }
            _ => return Ok(()),
        };
        let digits = token.strip_prefix(['+', '-']).unwrap_or(token);
        if digits.is_empty() || !digits.bytes().all(|b| b.is_ascii_digit()) {
            return Ok(());
        }
        let fits = token.parse::<i128>().is_ok_and(|v| (lo..=hi).contains(&v));
        if fits {
            return Ok(());
        }
        Err(Box::new(TextValueError {
            index,
            value: token.to_string(),
            type_name: declared.vtk_xml_name(),
            lo,
            hi,
        }))
    }

    /// Like [`TypedBuffer::from_f64`] but keeps the scalar type the file declared.
    pub fn from_f64_as(values: Vec<f64>, declared: ScalarType) -> Self {
        TypedBuffer {
            declared,
            ..Self::from_f64(values)
        }
    }

    /// The scalar type the file declared.
    pub fn scalar_type(&self) -> ScalarType {
        self.declared
    }

    /// Number of values.
    pub fn len(&self) -> usize {
        self.bytes.len() / self.storage.size()
    }

    /// Whether there is no value.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The stored type, byte order and bytes, for decoders that work on the bytes directly
    /// (the table-driven path for 8/16-bit integers).
    pub(super) fn raw(&self) -> (ScalarType, ByteOrder, &[u8]) {
        (self.storage, self.byte_order, &self.bytes)
    }

    /// Call `f` with every value as f64, in order.
    pub fn for_each(&self, f: impl FnMut(f64)) {
        for_each_value(self.storage, self.byte_order, &self.bytes, f);
    }
}

/// Call `f` with every value of `bytes` (values of type `ty` in byte order `order`; a
/// trailing partial value is ignored) as f64, in order. Shared by [`TypedBuffer`] and the
/// memory-mapped sources (`source`), so both decode alike.
pub(super) fn for_each_value(
    ty: ScalarType,
    order: ByteOrder,
    bytes: &[u8],
    mut f: impl FnMut(f64),
) {
    macro_rules! each {
        ($t:ty) => {{
            const N: usize = std::mem::size_of::<$t>();
            for c in bytes.chunks_exact(N) {
                let a: [u8; N] = c.try_into().expect("chunk of N bytes");
                let v = match order {
                    ByteOrder::Little => <$t>::from_le_bytes(a),
                    ByteOrder::Big => <$t>::from_be_bytes(a),
                };
                f(v as f64);
            }
        }};
    }
    match ty {
        ScalarType::U8 => each!(u8),
        ScalarType::I8 => each!(i8),
        ScalarType::U16 => each!(u16),
        ScalarType::I16 => each!(i16),
        ScalarType::U32 => each!(u32),
        ScalarType::I32 => each!(i32),
        ScalarType::U64 => each!(u64),
        ScalarType::I64 => each!(i64),
        ScalarType::F32 => each!(f32),
        ScalarType::F64 => each!(f64),
    }
}
