//! A restricted unpickler for the `data.pkl` of a `torch.save` archive, in the spirit of
//! torch's `weights_only=True`: nothing in the file is ever executed.
//!
//! A pickle is a program for a small stack machine; `GLOBAL` names a Python object and `REDUCE`
//! calls it, which is how a hostile file runs `os.system`. Here a global resolves only if it is
//! one of the few a state dict needs (`collections.OrderedDict`, torch's tensor/parameter
//! rebuild functions, storage classes and dtypes); any other name is refused on sight, before
//! anything could be called. The allowed "calls" are interpreted, not executed: rebuilding a
//! tensor records where its bytes live (storage key, dtype, offset, shape, strides) and reads
//! nothing.
//!
//! Opcodes are those `torch.save` emits with pickle protocols 2–5, plus a few harmless stack
//! operations. Opcodes that would reach other objects (`INST`, `OBJ`, `EXT1/2/4`, text
//! `PERSID`) are not implemented, so they are errors. Everything is bounded: strings and
//! lengths against the bytes left, the number of values, stack and memo sizes; values live in
//! one arena and are shared by index, so `BINGET` never copies and a self-referencing list is
//! just a cycle of indices. A hostile or truncated pickle gives an error, never a panic or a
//! large allocation.

use std::collections::{HashMap, HashSet};
use std::fmt;

/// Most values the machine may create (each opcode creates at most one): far above the few
/// thousand a CLIP state dict's pickle makes, far below what would strain memory.
const MAX_NODES: usize = 1 << 22;
/// Deepest value stack and memo: a state dict needs tens of stack slots (`SETITEMS` batches
/// 1000 pairs) and one memo entry per distinct object.
const MAX_STACK: usize = 1 << 20;
const MAX_MEMO: usize = 1 << 22;
const MAX_MARKS: usize = 1 << 12;
/// A tensor rank beyond this is corruption, not a model.
const MAX_RANK: usize = 32;
/// Module and attribute names after `GLOBAL` are short identifiers.
const MAX_GLOBAL_LINE: usize = 256;
/// How deep nested dicts are flattened into dotted names (`{"model": state_dict}`).
const MAX_DICT_DEPTH: usize = 8;

/// Why a pickle was not loaded.
#[derive(Debug, Clone, PartialEq)]
pub(crate) enum PickleError {
    /// The pickle names a global outside the allow-list (`"os.system"`).
    Refused(String),
    /// Truncated, corrupt, or using a construct a state dict never does.
    Malformed(String),
}

impl fmt::Display for PickleError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            PickleError::Refused(global) => write!(
                f,
                "refusing to load: the checkpoint's pickle calls {global}, which a PyTorch \
                 state dict never needs (t2tf loads only tensors)"
            ),
            PickleError::Malformed(msg) => write!(f, "{msg}"),
        }
    }
}

type Result<T> = std::result::Result<T, PickleError>;

fn bad<T>(msg: impl Into<String>) -> Result<T> {
    Err(PickleError::Malformed(msg.into()))
}

/// Element types torch can store. Only the float ones are ever converted; the others are
/// listed so a checkpoint with, say, int64 `position_ids` buffers still opens.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum DType {
    F64,
    F32,
    F16,
    BF16,
    I64,
    I32,
    I16,
    I8,
    U8,
    Bool,
    U16,
    U32,
    U64,
    F8E4M3,
    F8E5M2,
}

impl DType {
    /// Bytes per element.
    pub(crate) fn size(self) -> usize {
        match self {
            DType::F64 | DType::I64 | DType::U64 => 8,
            DType::F32 | DType::I32 | DType::U32 => 4,
            DType::F16 | DType::BF16 | DType::I16 | DType::U16 => 2,
            DType::I8 | DType::U8 | DType::Bool | DType::F8E4M3 | DType::F8E5M2 => 1,
        }
    }

    /// torch's name for it, as in error messages.
    pub(crate) fn name(self) -> &'static str {
        match self {
            DType::F64 => "float64",
            DType::F32 => "float32",
            DType::F16 => "float16",
            DType::BF16 => "bfloat16",
            DType::I64 => "int64",
            DType::I32 => "int32",
            DType::I16 => "int16",
            DType::I8 => "int8",
            DType::U8 => "uint8",
            DType::Bool => "bool",
            DType::U16 => "uint16",
            DType::U32 => "uint32",
            DType::U64 => "uint64",
            DType::F8E4M3 => "float8_e4m3fn",
            DType::F8E5M2 => "float8_e5m2",
        }
    }

    /// The legacy typed-storage class (`torch.FloatStorage`) that stands for this dtype in
    /// the persistent ids `_rebuild_tensor_v2` tensors use.
    fn from_storage_class(name: &str) -> Option<DType> {
        Some(match name {
            "DoubleStorage" => DType::F64,
            "FloatStorage" => DType::F32,
            "HalfStorage" => DType::F16,
            "BFloat16Storage" => DType::BF16,
            "LongStorage" => DType::I64,
            "IntStorage" => DType::I32,
            "ShortStorage" => DType::I16,
            "CharStorage" => DType::I8,
            "ByteStorage" => DType::U8,
            "BoolStorage" => DType::Bool,
            _ => return None,
        })
    }

    /// `torch.float32` etc., which newer torch pickles next to an `UntypedStorage`.
    fn from_dtype_attr(name: &str) -> Option<DType> {
        Some(match name {
            "float64" | "double" => DType::F64,
            "float32" | "float" => DType::F32,
            "float16" | "half" => DType::F16,
            "bfloat16" => DType::BF16,
            "int64" | "long" => DType::I64,
            "int32" | "int" => DType::I32,
            "int16" | "short" => DType::I16,
            "int8" => DType::I8,
            "uint8" => DType::U8,
            "bool" => DType::Bool,
            "uint16" => DType::U16,
            "uint32" => DType::U32,
            "uint64" => DType::U64,
            "float8_e4m3fn" => DType::F8E4M3,
            "float8_e5m2" => DType::F8E5M2,
            _ => return None,
        })
    }
}

/// One storage of the archive (`PREFIX/data/KEY`), as a persistent id names it.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Storage {
    pub(crate) key: String,
    pub(crate) dtype: DType,
    /// Elements of `dtype` the storage holds.
    pub(crate) numel: u64,
}

/// A tensor view on a storage: element `[i, j, ..]` is storage element
/// `offset + i*stride[0] + j*stride[1] + ..`, in units of `dtype`.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Tensor {
    pub(crate) storage: Storage,
    pub(crate) dtype: DType,
    pub(crate) offset: usize,
    pub(crate) shape: Vec<usize>,
    pub(crate) stride: Vec<usize>,
}

/// The allowed globals. Anything else is refused when it is named.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Global {
    OrderedDict,
    RebuildTensor,
    RebuildTensorV2,
    RebuildTensorV3,
    RebuildParameter,
    RebuildParameterWithState,
    StorageClass(DType),
    UntypedStorage,
    DTypeAttr(DType),
}

fn resolve_global(module: &str, name: &str) -> Option<Global> {
    Some(match (module, name) {
        ("collections", "OrderedDict") => Global::OrderedDict,
        ("torch._utils", "_rebuild_tensor") => Global::RebuildTensor,
        ("torch._utils", "_rebuild_tensor_v2") => Global::RebuildTensorV2,
        ("torch._utils", "_rebuild_tensor_v3") => Global::RebuildTensorV3,
        ("torch._utils", "_rebuild_parameter") => Global::RebuildParameter,
        ("torch._utils", "_rebuild_parameter_with_state") => Global::RebuildParameterWithState,
        // torch pickles the class where it is defined, `torch.storage`.
        ("torch" | "torch.storage", "UntypedStorage") => Global::UntypedStorage,
        ("torch", n) => DType::from_storage_class(n)
            .map(Global::StorageClass)
            .or_else(|| DType::from_dtype_attr(n).map(Global::DTypeAttr))?,
        _ => return None,
    })
}

/// A pickled value. Containers hold arena indices, so sharing (`BINGET`) is free and
/// mutation through one reference is seen through all, as in Python.
#[derive(Debug)]
enum Node {
    None,
    /// Booleans and floats appear in state dicts (`requires_grad`, metadata) but are never
    /// looked at: only their kind is kept, for messages.
    Bool,
    Int(i64),
    Float,
    Str(String),
    /// A value a state dict may carry but t2tf never looks at (bytes).
    Opaque,
    Tuple(Vec<usize>),
    List(Vec<usize>),
    Dict(Vec<(usize, usize)>),
    Global(Global),
    Storage(Storage),
    Tensor(Tensor),
}

impl Node {
    fn kind(&self) -> &'static str {
        match self {
            Node::None => "None",
            Node::Bool => "a bool",
            Node::Int(_) => "an int",
            Node::Float => "a float",
            Node::Str(_) => "a string",
            Node::Opaque => "bytes",
            Node::Tuple(_) => "a tuple",
            Node::List(_) => "a list",
            Node::Dict(_) => "a dict",
            Node::Global(_) => "a class or function",
            Node::Storage(_) => "a storage",
            Node::Tensor(_) => "a tensor",
        }
    }
}

/// Run the pickle and return every tensor of the state dict it builds, in pickle order,
/// nested dicts flattened with `.` (a later duplicate name replaces an earlier one).
pub(crate) fn load_tensors(pickle: &[u8]) -> Result<Vec<(String, Tensor)>> {
    let mut m = Machine::new(pickle);
    let root = m.run()?;
    m.collect_tensors(root)
}

struct Machine<'a> {
    input: &'a [u8],
    pos: usize,
    nodes: Vec<Node>,
    stack: Vec<usize>,
    /// Stack lengths at each `MARK`, innermost last.
    marks: Vec<usize>,
    memo: HashMap<u32, usize>,
}

// Opcodes (CPython's Lib/pickletools.py documents each).
const MARK: u8 = b'(';
const STOP: u8 = b'.';
const POP: u8 = b'0';
const POP_MARK: u8 = b'1';
const DUP: u8 = b'2';
const BININT: u8 = b'J';
const BININT1: u8 = b'K';
const BININT2: u8 = b'M';
const NONE: u8 = b'N';
const BINPERSID: u8 = b'Q';
const REDUCE: u8 = b'R';
const BINUNICODE: u8 = b'X';
const SHORT_BINBYTES: u8 = b'C';
const BINBYTES: u8 = b'B';
const APPEND: u8 = b'a';
const BUILD: u8 = b'b';
const GLOBAL: u8 = b'c';
const DICT: u8 = b'd';
const EMPTY_DICT: u8 = b'}';
const APPENDS: u8 = b'e';
const BINGET: u8 = b'h';
const LONG_BINGET: u8 = b'j';
const LIST: u8 = b'l';
const EMPTY_LIST: u8 = b']';
const BINPUT: u8 = b'q';
const LONG_BINPUT: u8 = b'r';
const SETITEM: u8 = b's';
const TUPLE: u8 = b't';
const EMPTY_TUPLE: u8 = b')';
const SETITEMS: u8 = b'u';
const BINFLOAT: u8 = b'G';
const PROTO: u8 = 0x80;
const NEWOBJ: u8 = 0x81;
const TUPLE1: u8 = 0x85;
const TUPLE2: u8 = 0x86;
const TUPLE3: u8 = 0x87;
const NEWTRUE: u8 = 0x88;
const NEWFALSE: u8 = 0x89;
const LONG1: u8 = 0x8a;
const LONG4: u8 = 0x8b;
const SHORT_BINUNICODE: u8 = 0x8c;
const BINUNICODE8: u8 = 0x8d;
const BINBYTES8: u8 = 0x8e;
const NEWOBJ_EX: u8 = 0x92;
const STACK_GLOBAL: u8 = 0x93;
const MEMOIZE: u8 = 0x94;
const FRAME: u8 = 0x95;

impl<'a> Machine<'a> {
    fn new(input: &'a [u8]) -> Machine<'a> {
        Machine {
            input,
            pos: 0,
            nodes: Vec::new(),
            stack: Vec::new(),
            marks: Vec::new(),
            memo: HashMap::new(),
        }
    }

    /// Execute until `STOP`; the value left on the stack is the result.
    fn run(&mut self) -> Result<usize> {
        loop {
            let at = self.pos;
            let op = self.u8()?;
            if op == STOP {
                return self.pop();
            }
            self.step(op).map_err(|e| match e {
                PickleError::Malformed(m) => {
                    PickleError::Malformed(format!("pickle opcode 0x{op:02x} at byte {at}: {m}"))
                }
                refused => refused,
            })?;
        }
    }

    fn step(&mut self, op: u8) -> Result<()> {
        match op {
            PROTO => self.proto(),
            FRAME => self.bytes(8).map(|_| ()), // a framing hint; the bytes follow inline
            MARK => self.mark(),
            POP => self.pop().map(|_| ()),
            POP_MARK => self.pop_mark().map(|_| ()),
            DUP => {
                let top = self.top()?;
                self.push_index(top)
            }
            NONE => self.push(Node::None),
            NEWTRUE | NEWFALSE => self.push(Node::Bool),
            BININT => {
                let v = i32::from_le_bytes(self.array()?);
                self.push(Node::Int(v.into()))
            }
            BININT1 => {
                let v = self.u8()?;
                self.push(Node::Int(v.into()))
            }
            BININT2 => {
                let v = u16::from_le_bytes(self.array()?);
                self.push(Node::Int(v.into()))
            }
            LONG1 => {
                let n = self.u8()?.into();
                self.long(n)
            }
            LONG4 => {
                let n = self.len_u32()?;
                self.long(n)
            }
            BINFLOAT => {
                self.array::<8>()?;
                self.push(Node::Float)
            }
            // The string and bytes opcodes differ only in the width of their length prefix
            // (u8, u32, u64); one arm per opcode keeps this table readable against
            // Python's `pickletools` listing.
            SHORT_BINUNICODE => {
                let n = self.u8()?.into();
                self.unicode(n)
            }
            BINUNICODE => {
                let n = self.len_u32()?;
                self.unicode(n)
            }
            BINUNICODE8 => {
                let n = self.len_u64()?;
                self.unicode(n)
            }
            SHORT_BINBYTES => {
                let n = self.u8()?.into();
                self.opaque_bytes(n)
            }
            BINBYTES => {
                let n = self.len_u32()?;
                self.opaque_bytes(n)
            }
            BINBYTES8 => {
                let n = self.len_u64()?;
                self.opaque_bytes(n)
            }
            EMPTY_TUPLE => self.push(Node::Tuple(Vec::new())),
            TUPLE1 | TUPLE2 | TUPLE3 => self.small_tuple(usize::from(op - TUPLE1) + 1),
            TUPLE => {
                let items = self.pop_mark()?;
                self.push(Node::Tuple(items))
            }
            EMPTY_LIST => self.push(Node::List(Vec::new())),
            LIST => {
                let items = self.pop_mark()?;
                self.push(Node::List(items))
            }
            EMPTY_DICT => self.push(Node::Dict(Vec::new())),
            DICT => {
                let items = self.pop_mark()?;
                let pairs = pairs(&items)?;
                self.push(Node::Dict(pairs))
            }
            APPEND => {
                let v = self.pop()?;
                self.extend_list(vec![v])
            }
            APPENDS => {
                let items = self.pop_mark()?;
                self.extend_list(items)
            }
            SETITEM => {
                let v = self.pop()?;
                let k = self.pop()?;
                self.extend_dict(vec![(k, v)])
            }
            SETITEMS => {
                let items = self.pop_mark()?;
                let pairs = pairs(&items)?;
                self.extend_dict(pairs)
            }
            BINPUT => {
                let i = self.u8()?.into();
                self.memo_put(i)
            }
            LONG_BINPUT => {
                let i = u32::from_le_bytes(self.array()?);
                self.memo_put(i)
            }
            MEMOIZE => {
                let i = u32::try_from(self.memo.len()).or_else(|_| bad("memo is full"))?;
                self.memo_put(i)
            }
            BINGET => {
                let i = self.u8()?.into();
                self.memo_get(i)
            }
            LONG_BINGET => {
                let i = u32::from_le_bytes(self.array()?);
                self.memo_get(i)
            }
            GLOBAL => self.global_inline(),
            STACK_GLOBAL => self.global_stack(),
            REDUCE => {
                let args = self.pop()?;
                let callable = self.pop()?;
                self.call(callable, args)
            }
            NEWOBJ => {
                let args = self.pop()?;
                let class = self.pop()?;
                self.new_object(class, args)
            }
            NEWOBJ_EX => {
                let kwargs = self.pop()?;
                let args = self.pop()?;
                let class = self.pop()?;
                self.expect_empty(kwargs, "keyword arguments")?;
                self.new_object(class, args)
            }
            BUILD => self.build(),
            BINPERSID => {
                let pid = self.pop()?;
                let storage = self.persistent_storage(pid)?;
                self.push(Node::Storage(storage))
            }
            _ => bad("not an opcode torch.save writes for a state dict"),
        }
    }

    // ---- reading the input ----

    fn bytes(&mut self, n: usize) -> Result<&'a [u8]> {
        let left = self.input.len() - self.pos;
        if n > left {
            return bad(format!(
                "needs {n} more bytes but the pickle has {left} left (truncated?)"
            ));
        }
        let s = &self.input[self.pos..self.pos + n];
        self.pos += n;
        Ok(s)
    }

    fn array<const N: usize>(&mut self) -> Result<[u8; N]> {
        let mut a = [0u8; N];
        a.copy_from_slice(self.bytes(N)?);
        Ok(a)
    }

    fn u8(&mut self) -> Result<u8> {
        if self.pos >= self.input.len() {
            return bad(format!(
                "the pickle ends at byte {} without STOP (truncated?)",
                self.pos
            ));
        }
        self.pos += 1;
        Ok(self.input[self.pos - 1])
    }

    fn len_u32(&mut self) -> Result<usize> {
        let n = u32::from_le_bytes(self.array()?);
        usize::try_from(n).or_else(|_| bad("length does not fit in memory"))
    }

    fn len_u64(&mut self) -> Result<usize> {
        let n = u64::from_le_bytes(self.array()?);
        usize::try_from(n).or_else(|_| bad("length does not fit in memory"))
    }

    /// A line after `GLOBAL`, without its newline.
    fn line(&mut self) -> Result<&'a str> {
        let rest = &self.input[self.pos..];
        let window = &rest[..rest.len().min(MAX_GLOBAL_LINE)];
        let Some(n) = window.iter().position(|&b| b == b'\n') else {
            return bad("GLOBAL name is not a short newline-terminated line");
        };
        let line = self.bytes(n + 1)?;
        std::str::from_utf8(&line[..n]).or_else(|_| bad("GLOBAL name is not UTF-8"))
    }

    fn proto(&mut self) -> Result<()> {
        let v = self.u8()?;
        if !(2..=5).contains(&v) {
            return bad(format!("pickle protocol {v} (torch.save writes 2 to 5)"));
        }
        Ok(())
    }

    fn long(&mut self, n: usize) -> Result<()> {
        if n > 8 {
            return bad(format!("a {n}-byte integer (larger than any tensor size)"));
        }
        let b = self.bytes(n)?;
        // Little-endian two's complement of n bytes, sign-extended to 64 bits.
        let mut buf = if b.last().is_some_and(|&x| x & 0x80 != 0) {
            [0xffu8; 8]
        } else {
            [0u8; 8]
        };
        buf[..n].copy_from_slice(b);
        self.push(Node::Int(i64::from_le_bytes(buf)))
    }

    fn unicode(&mut self, n: usize) -> Result<()> {
        // `bytes` checks `n` against what is left before anything is allocated.
        let b = self.bytes(n)?;
        let s = std::str::from_utf8(b).or_else(|_| bad("string is not UTF-8"))?;
        self.push(Node::Str(s.to_owned()))
    }

    fn opaque_bytes(&mut self, n: usize) -> Result<()> {
        self.bytes(n)?;
        self.push(Node::Opaque)
    }

    // ---- the stack, marks and memo ----

    fn push(&mut self, node: Node) -> Result<()> {
        if self.nodes.len() >= MAX_NODES {
            return bad(format!("more than {MAX_NODES} values"));
        }
        self.nodes.push(node);
        self.push_index(self.nodes.len() - 1)
    }

    fn push_index(&mut self, i: usize) -> Result<()> {
        if self.stack.len() >= MAX_STACK {
            return bad(format!("stack deeper than {MAX_STACK}"));
        }
        self.stack.push(i);
        Ok(())
    }

    fn pop(&mut self) -> Result<usize> {
        // A MARK is a boundary: items below it belong to an unfinished container.
        let floor = self.marks.last().copied().unwrap_or(0);
        if self.stack.len() <= floor {
            return bad("stack underflow");
        }
        self.stack.pop().map_or_else(|| bad("stack underflow"), Ok)
    }

    fn top(&self) -> Result<usize> {
        let floor = self.marks.last().copied().unwrap_or(0);
        if self.stack.len() <= floor {
            return bad("stack underflow");
        }
        self.stack
            .last()
            .map_or_else(|| bad("stack underflow"), |&i| Ok(i))
    }

    fn mark(&mut self) -> Result<()> {
        if self.marks.len() >= MAX_MARKS {
            return bad(format!("more than {MAX_MARKS} nested MARKs"));
        }
        self.marks.push(self.stack.len());
        Ok(())
    }

    fn pop_mark(&mut self) -> Result<Vec<usize>> {
        let Some(at) = self.marks.pop() else {
            return bad("no MARK to pop to");
        };
        Ok(self.stack.split_off(at))
    }

    fn memo_put(&mut self, i: u32) -> Result<()> {
        let top = self.top()?;
        if self.memo.len() >= MAX_MEMO && !self.memo.contains_key(&i) {
            return bad(format!("memo larger than {MAX_MEMO}"));
        }
        self.memo.insert(i, top);
        Ok(())
    }

    fn memo_get(&mut self, i: u32) -> Result<()> {
        match self.memo.get(&i) {
            Some(&node) => self.push_index(node),
            None => bad(format!("memo slot {i} is empty")),
        }
    }

    // ---- containers ----

    fn small_tuple(&mut self, n: usize) -> Result<()> {
        let mut items = vec![0; n];
        for slot in items.iter_mut().rev() {
            *slot = self.pop()?;
        }
        self.push(Node::Tuple(items))
    }

    fn extend_list(&mut self, items: Vec<usize>) -> Result<()> {
        let target = self.top()?;
        match &mut self.nodes[target] {
            Node::List(list) => {
                list.extend(items);
                Ok(())
            }
            other => bad(format!("APPEND to {}", other.kind())),
        }
    }

    fn extend_dict(&mut self, pairs: Vec<(usize, usize)>) -> Result<()> {
        let target = self.top()?;
        match &mut self.nodes[target] {
            Node::Dict(dict) => {
                dict.extend(pairs);
                Ok(())
            }
            other => bad(format!("SETITEM on {}", other.kind())),
        }
    }

    // ---- globals and calls ----

    fn global_inline(&mut self) -> Result<()> {
        let module = self.line()?;
        let name = self.line()?;
        self.push_global(module, name)
    }

    fn global_stack(&mut self) -> Result<()> {
        let name = self.pop()?;
        let module = self.pop()?;
        let (Node::Str(module), Node::Str(name)) = (&self.nodes[module], &self.nodes[name]) else {
            return bad("STACK_GLOBAL needs two strings");
        };
        let (module, name) = (module.clone(), name.clone());
        self.push_global(&module, &name)
    }

    fn push_global(&mut self, module: &str, name: &str) -> Result<()> {
        match resolve_global(module, name) {
            Some(g) => self.push(Node::Global(g)),
            None => Err(PickleError::Refused(printable(&format!("{module}.{name}")))),
        }
    }

    fn global_of(&self, i: usize) -> Result<Global> {
        match &self.nodes[i] {
            Node::Global(g) => Ok(*g),
            other => bad(format!("cannot call {}", other.kind())),
        }
    }

    fn tuple_of(&self, i: usize, what: &str) -> Result<&[usize]> {
        match &self.nodes[i] {
            Node::Tuple(items) => Ok(items),
            other => bad(format!("{what} must be a tuple, not {}", other.kind())),
        }
    }

    /// `REDUCE`: `callable(*args)` for the allowed callables.
    fn call(&mut self, callable: usize, args: usize) -> Result<()> {
        let g = self.global_of(callable)?;
        let args = self.tuple_of(args, "REDUCE arguments")?.to_vec();
        let arity = |ok: &[usize]| -> Result<()> {
            if ok.contains(&args.len()) {
                Ok(())
            } else {
                bad(format!("{g:?} with {} arguments", args.len()))
            }
        };
        match g {
            Global::OrderedDict => {
                arity(&[0])?;
                self.push(Node::Dict(Vec::new()))
            }
            Global::RebuildTensor => {
                arity(&[4])?;
                let t = self.rebuild_tensor(&args, None)?;
                self.push(Node::Tensor(t))
            }
            Global::RebuildTensorV2 => {
                arity(&[6, 7])?;
                let t = self.rebuild_tensor(&args, None)?;
                self.push(Node::Tensor(t))
            }
            Global::RebuildTensorV3 => {
                arity(&[7, 8])?;
                let dtype = match self.nodes[args[6]] {
                    Node::Global(Global::DTypeAttr(d)) => d,
                    ref other => return bad(format!("tensor dtype is {}", other.kind())),
                };
                let t = self.rebuild_tensor(&args, Some(dtype))?;
                self.push(Node::Tensor(t))
            }
            Global::RebuildParameter | Global::RebuildParameterWithState => {
                arity(if g == Global::RebuildParameter {
                    &[3]
                } else {
                    &[4]
                })?;
                // A Parameter is its data tensor; requires_grad and hooks do not matter here.
                match self.nodes[args[0]] {
                    Node::Tensor(_) => self.push_index(args[0]),
                    ref other => bad(format!("parameter data is {}", other.kind())),
                }
            }
            Global::StorageClass(_) | Global::UntypedStorage | Global::DTypeAttr(_) => {
                bad(format!("{g:?} is not callable in a state dict"))
            }
        }
    }

    /// `NEWOBJ`: `cls.__new__(cls, *args)`; only `OrderedDict` is a class we build.
    fn new_object(&mut self, class: usize, args: usize) -> Result<()> {
        match self.global_of(class)? {
            Global::OrderedDict => {
                self.expect_empty(args, "OrderedDict arguments")?;
                self.push(Node::Dict(Vec::new()))
            }
            g => bad(format!("cannot instantiate {g:?}")),
        }
    }

    fn expect_empty(&self, i: usize, what: &str) -> Result<()> {
        match &self.nodes[i] {
            Node::Tuple(v) if v.is_empty() => Ok(()),
            Node::Dict(v) if v.is_empty() => Ok(()),
            _ => bad(format!("{what} must be empty")),
        }
    }

    /// `BUILD`: set an object's state. A state dict's `_metadata` and a tensor's Python
    /// attributes arrive this way; neither holds weights, so the state is dropped.
    fn build(&mut self) -> Result<()> {
        self.pop()?;
        let target = self.top()?;
        match &self.nodes[target] {
            Node::Dict(_) | Node::Tensor(_) => Ok(()),
            other => bad(format!("BUILD on {}", other.kind())),
        }
    }

    /// `BINPERSID` with torch's id `("storage", storage_type, key, location, numel)`.
    fn persistent_storage(&self, pid: usize) -> Result<Storage> {
        let f = self.tuple_of(pid, "persistent id")?;
        let [tag, kind, key, _location, numel] = f else {
            return bad(format!(
                "persistent id with {} fields (torch writes 5)",
                f.len()
            ));
        };
        if !matches!(&self.nodes[*tag], Node::Str(s) if s == "storage") {
            return bad("persistent id is not a storage");
        }
        let dtype = match self.nodes[*kind] {
            Node::Global(Global::StorageClass(d) | Global::DTypeAttr(d)) => d,
            Node::Global(Global::UntypedStorage) => DType::U8,
            ref other => return bad(format!("storage type is {}", other.kind())),
        };
        let Node::Str(key) = &self.nodes[*key] else {
            return bad("storage key is not a string");
        };
        let numel = self.int(*numel, "storage size")?;
        Ok(Storage {
            key: key.clone(),
            dtype,
            numel: numel as u64,
        })
    }

    /// Arguments `(storage, storage_offset, size, stride, ..)` of the rebuild functions;
    /// `dtype` is given for `_rebuild_tensor_v3`, whose storage is untyped bytes.
    fn rebuild_tensor(&self, args: &[usize], dtype: Option<DType>) -> Result<Tensor> {
        let Node::Storage(storage) = &self.nodes[args[0]] else {
            return bad(format!("tensor storage is {}", self.nodes[args[0]].kind()));
        };
        let offset = self.int(args[1], "storage offset")?;
        let shape = self.ints(args[2], "size")?;
        let stride = self.ints(args[3], "stride")?;
        if shape.len() != stride.len() {
            return bad(format!(
                "size {shape:?} and stride {stride:?} differ in length"
            ));
        }
        Ok(Tensor {
            storage: storage.clone(),
            dtype: dtype.unwrap_or(storage.dtype),
            offset,
            shape,
            stride,
        })
    }

    fn int(&self, i: usize, what: &str) -> Result<usize> {
        match self.nodes[i] {
            Node::Int(v) => usize::try_from(v).or_else(|_| bad(format!("{what} is {v}"))),
            ref other => bad(format!("{what} is {}", other.kind())),
        }
    }

    fn ints(&self, i: usize, what: &str) -> Result<Vec<usize>> {
        let items = self.tuple_of(i, what)?;
        if items.len() > MAX_RANK {
            return bad(format!("{what} has {} dimensions", items.len()));
        }
        items.iter().map(|&j| self.int(j, what)).collect()
    }

    // ---- the result ----

    /// Walk the root dict (and dicts inside it, each once) for tensors.
    fn collect_tensors(&self, root: usize) -> Result<Vec<(String, Tensor)>> {
        if !matches!(self.nodes[root], Node::Dict(_)) {
            return bad(format!(
                "the checkpoint holds {}, not a state dict",
                self.nodes[root].kind()
            ));
        }
        let mut out = Vec::new();
        let mut seen = HashSet::new();
        let mut todo = vec![(String::new(), root, 0usize)];
        while let Some((prefix, dict, depth)) = todo.pop() {
            let Node::Dict(pairs) = &self.nodes[dict] else {
                continue;
            };
            if !seen.insert(dict) {
                continue; // a dict reachable twice (or from itself) is walked once
            }
            for &(k, v) in pairs {
                let Node::Str(key) = &self.nodes[k] else {
                    continue; // non-string keys (optimizer state) name no weight
                };
                let name = format!("{prefix}{key}");
                match &self.nodes[v] {
                    Node::Tensor(t) => out.push((name, t.clone())),
                    Node::Dict(_) if depth < MAX_DICT_DEPTH => {
                        todo.push((format!("{name}."), v, depth + 1))
                    }
                    _ => {}
                }
            }
        }
        Ok(out)
    }
}

/// `[k0, v0, k1, v1, ..]` → pairs.
fn pairs(items: &[usize]) -> Result<Vec<(usize, usize)>> {
    if !items.len().is_multiple_of(2) {
        return bad("odd number of dict items");
    }
    Ok(items.chunks_exact(2).map(|kv| (kv[0], kv[1])).collect())
}

/// A global's name for an error message: at most 100 characters, control characters escaped.
fn printable(name: &str) -> String {
    let s: String = name.chars().take(100).collect();
    s.escape_debug().to_string()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A tiny pickle writer for hand-built programs.
    #[derive(Default)]
    struct P(Vec<u8>);

    impl P {
        fn op(mut self, op: u8) -> P {
            self.0.push(op);
            self
        }
        fn raw(mut self, b: &[u8]) -> P {
            self.0.extend_from_slice(b);
            self
        }
        fn proto(self) -> P {
            self.op(PROTO).raw(&[2])
        }
        fn global(self, module: &str, name: &str) -> P {
            self.op(GLOBAL)
                .raw(format!("{module}\n{name}\n").as_bytes())
        }
        fn str(self, s: &str) -> P {
            let n = (s.len() as u32).to_le_bytes();
            self.op(BINUNICODE).raw(&n).raw(s.as_bytes())
        }
        fn int(self, v: u8) -> P {
            self.op(BININT1).raw(&[v])
        }
        /// `("storage", torch.<class>, key, "cpu", numel)` + BINPERSID.
        fn storage(self, class: &str, key: &str, numel: u8) -> P {
            self.op(MARK)
                .str("storage")
                .global("torch", class)
                .str(key)
                .str("cpu")
                .int(numel)
                .op(TUPLE)
                .op(BINPERSID)
        }
        /// `_rebuild_tensor_v2(storage, offset, (shape), (stride), False, OrderedDict())`.
        fn tensor_v2(self, class: &str, key: &str, numel: u8, offset: u8, shape: &[u8]) -> P {
            let mut p = self
                .global("torch._utils", "_rebuild_tensor_v2")
                .op(MARK)
                .storage(class, key, numel)
                .int(offset)
                .op(MARK);
            for &d in shape {
                p = p.int(d);
            }
            p = p.op(TUPLE).op(MARK);
            let mut stride = vec![1u8; shape.len()];
            for i in (0..shape.len().saturating_sub(1)).rev() {
                stride[i] = stride[i + 1] * shape[i + 1];
            }
            for s in stride {
                p = p.int(s);
            }
            p.op(TUPLE)
                .op(NEWFALSE)
                .global("collections", "OrderedDict")
                .op(EMPTY_TUPLE)
                .op(REDUCE)
                .op(TUPLE)
                .op(REDUCE)
        }
        fn done(self) -> Vec<u8> {
            self.op(STOP).0
        }
    }

    fn state_dict_with(tensors: impl FnOnce(P) -> P) -> Vec<u8> {
        let p = P::default()
            .proto()
            .global("collections", "OrderedDict")
            .op(EMPTY_TUPLE)
            .op(REDUCE)
            .op(MARK);
        tensors(p).op(SETITEMS).done()
    }

    #[test]
    fn reads_a_hand_built_state_dict() {
        let pkl = state_dict_with(|p| {
            p.str("w")
                .tensor_v2("HalfStorage", "0", 6, 0, &[2, 3])
                .str("b")
                .tensor_v2("LongStorage", "1", 3, 1, &[2])
        });
        let t = load_tensors(&pkl).unwrap();
        assert_eq!(t.len(), 2);
        assert_eq!(t[0].0, "w");
        assert_eq!(t[0].1.dtype, DType::F16);
        assert_eq!(t[0].1.shape, vec![2, 3]);
        assert_eq!(t[0].1.stride, vec![3, 1]);
        assert_eq!(t[1].0, "b");
        assert_eq!(t[1].1.storage.key, "1");
        assert_eq!(t[1].1.storage.numel, 3);
        assert_eq!(t[1].1.offset, 1);
    }

    #[test]
    fn refuses_globals_outside_the_allow_list() {
        let os = P::default()
            .proto()
            .global("os", "system")
            .str("touch marker")
            .op(TUPLE1)
            .op(REDUCE)
            .done();
        let e = load_tensors(&os).unwrap_err();
        assert_eq!(e, PickleError::Refused("os.system".into()));
        let msg = e.to_string();
        assert!(
            msg.contains("refusing to load") && msg.contains("os.system"),
            "{msg}"
        );

        // The protocol-4 form names the global through two strings on the stack.
        let eval = P::default()
            .proto()
            .str("builtins")
            .str("eval")
            .op(STACK_GLOBAL)
            .done();
        let e = load_tensors(&eval).unwrap_err();
        assert_eq!(e, PickleError::Refused("builtins.eval".into()));

        // torch itself has dangerous attributes too (torch.load, torch.hub.*).
        let torch_load = P::default().proto().global("torch", "load").done();
        assert_eq!(
            load_tensors(&torch_load).unwrap_err(),
            PickleError::Refused("torch.load".into())
        );
        // An unprintable name is escaped in the message, not written raw to a terminal.
        let weird = P::default().proto().global("x\x1b[2J", "y").done();
        let e = load_tensors(&weird).unwrap_err().to_string();
        assert!(e.contains("\\u{1b}") && !e.contains('\x1b'), "{e}");
    }

    #[test]
    fn opcodes_that_reach_objects_indirectly_are_unsupported() {
        // INST, OBJ, EXT1 and text PERSID could name classes without GLOBAL.
        for op in [b'i', b'o', 0x82, b'P'] {
            let pkl = P::default().proto().op(op).raw(b"os\nsystem\n").done();
            let e = load_tensors(&pkl).unwrap_err();
            assert!(
                matches!(&e, PickleError::Malformed(m) if m.contains("not an opcode")),
                "{e:?}"
            );
        }
    }

    #[test]
    fn lengths_are_checked_before_allocating() {
        // BINUNICODE claiming 4 GiB, BINUNICODE8 claiming 2^63, and a 255-byte LONG1.
        let huge = P::default().proto().op(BINUNICODE).raw(&[0xff; 4]).done();
        assert!(load_tensors(&huge)
            .unwrap_err()
            .to_string()
            .contains("truncated"));
        let huge8 = P::default().proto().op(BINUNICODE8).raw(&[0xff; 8]).done();
        assert!(load_tensors(&huge8).is_err());
        let long = P::default().proto().op(LONG1).raw(&[255]).done();
        assert!(load_tensors(&long)
            .unwrap_err()
            .to_string()
            .contains("integer"));
        // A far memo slot costs one map entry, not a 4-billion-slot table.
        let far = P::default()
            .proto()
            .op(EMPTY_DICT)
            .op(LONG_BINPUT)
            .raw(&[0xff; 4])
            .op(LONG_BINGET)
            .raw(&[0xff; 4])
            .op(POP)
            .done();
        assert!(load_tensors(&far).unwrap().is_empty());
    }

    #[test]
    fn stack_and_marks_are_bounded() {
        let deep = P::default().proto().raw(&vec![MARK; MAX_MARKS + 1]).done();
        assert!(load_tensors(&deep)
            .unwrap_err()
            .to_string()
            .contains("MARK"));
        // POP may not reach below the innermost MARK; a lone STOP has nothing to return.
        let under = P::default().proto().op(NONE).op(MARK).op(POP).done();
        assert!(load_tensors(&under)
            .unwrap_err()
            .to_string()
            .contains("underflow"));
        assert!(load_tensors(&P::default().done()).is_err());
    }

    #[test]
    fn a_dict_containing_itself_is_walked_once() {
        // d = {}; d["self"] = d; d["w"] = tensor
        let pkl = P::default()
            .proto()
            .op(EMPTY_DICT)
            .op(BINPUT)
            .raw(&[0])
            .str("self")
            .op(BINGET)
            .raw(&[0])
            .op(SETITEM)
            .str("w")
            .tensor_v2("FloatStorage", "0", 1, 0, &[])
            .op(SETITEM)
            .done();
        let t = load_tensors(&pkl).unwrap();
        let names: Vec<&str> = t.iter().map(|(n, _)| n.as_str()).collect();
        assert_eq!(names, ["w"]);
    }

    #[test]
    fn nested_dicts_are_flattened_and_metadata_is_ignored() {
        // {"model": {"w": t}} with BUILD state on the inner dict, as state_dict() pickles.
        let pkl = P::default()
            .proto()
            .op(EMPTY_DICT)
            .str("model")
            .global("collections", "OrderedDict")
            .op(EMPTY_TUPLE)
            .op(REDUCE)
            .str("w")
            .tensor_v2("FloatStorage", "0", 2, 0, &[2])
            .op(SETITEM)
            .op(EMPTY_DICT)
            .str("_metadata")
            .op(EMPTY_DICT)
            .op(SETITEM)
            .op(BUILD)
            .op(SETITEM)
            .done();
        let t = load_tensors(&pkl).unwrap();
        assert_eq!(t.len(), 1);
        assert_eq!(t[0].0, "model.w");
    }

    #[test]
    fn rebuild_arguments_are_type_checked() {
        // _rebuild_tensor_v2 given an int where the storage belongs.
        let pkl = state_dict_with(|p| {
            p.str("w")
                .global("torch._utils", "_rebuild_tensor_v2")
                .op(MARK)
                .int(0)
                .int(0)
                .op(EMPTY_TUPLE)
                .op(EMPTY_TUPLE)
                .op(NEWFALSE)
                .op(NONE)
                .op(TUPLE)
                .op(REDUCE)
        });
        let e = load_tensors(&pkl).unwrap_err().to_string();
        assert!(e.contains("storage is an int"), "{e}");
        // A storage class is not something to call.
        let pkl = P::default()
            .proto()
            .global("torch", "FloatStorage")
            .op(EMPTY_TUPLE)
            .op(REDUCE)
            .done();
        assert!(load_tensors(&pkl)
            .unwrap_err()
            .to_string()
            .contains("not callable"));
    }

    #[test]
    fn negative_and_wide_integers_decode() {
        for (bytes, want) in [
            (vec![0xff], -1i64),
            (vec![0x00, 0x01], 256),
            (vec![0x80], -128),
            (vec![], 0),
            (vec![0xff; 8], -1),
        ] {
            let mut m = Machine::new(&bytes);
            m.long(bytes.len()).unwrap();
            let top = m.stack.pop().unwrap();
            assert!(matches!(m.nodes[top], Node::Int(v) if v == want), "{want}");
        }
    }

    #[test]
    fn every_prefix_and_mutation_is_an_error_or_ok_never_a_panic() {
        let pkl = state_dict_with(|p| {
            p.str("w")
                .tensor_v2("FloatStorage", "0", 6, 0, &[2, 3])
                .str("b")
                .tensor_v2("BFloat16Storage", "1", 3, 0, &[3])
        });
        for n in 0..pkl.len() {
            assert!(load_tensors(&pkl[..n]).is_err(), "prefix {n}");
        }
        // A deterministic spread of single-byte changes (xorshift, no rand dependency here).
        let mut s = 0x2545_f491_4f6c_dd1du64;
        for _ in 0..5000 {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            let mut m = pkl.clone();
            let i = (s % m.len() as u64) as usize;
            m[i] = (s >> 32) as u8;
            let _ = load_tensors(&m);
        }
    }
}
