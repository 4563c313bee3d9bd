//! Structure-aware differential fuzzing of the compiled engine, built as the controller is
//! (release, no overflow checks):
//!
//!     cargo run --release -p dribble-controller --example fuzz_engine -- --seconds 300
//!
//! Each case is a random small ONNX graph drawn from a seed: the operators the engine lowers
//! (Conv with any kernel, stride and padding, MaxPool, Relu, Flatten, Reshape, Squeeze,
//! Unsqueeze, Transpose, Gather, Concat, Gemm, MatMul, the element-wise operators, the
//! reductions, Cast, Identity, LSTM), shapes of both manifests' kinds (the cameras' images,
//! an R-CNN's step with its states, small tensors of any rank) and attributes that are
//! mostly valid and sometimes hostile (negative, zero, 2^24 + 1, 2^31, 2^61, i64's ends).
//! Every case both tract and the engine accept is run under both on every instruction set
//! this CPU has and compared ([`oracle::compare`]); a disagreement, a panic or a crash is a
//! finding. Findings are written to `--findings` as `<seed>.onnx` plus `<seed>.inputs`;
//! moved into `tests/fuzz/regressions/engine/` they are replayed by `cargo test`
//! (`controller/tests/engine_regressions.rs`). The seed being tried is written to
//! `<findings>/current-seed` first, so a crash (SIGSEGV) leaves it behind.

use std::path::PathBuf;
use std::time::{Duration, Instant};

use clap::Parser;
use dribble_controller::policy::engine::Isa;
use dribble_controller::policy::engine::onnx_builder::{Attribute, floats, ints, model, node};
use dribble_controller::policy::engine::oracle::{Comparison, compare};
use tract_onnx::pb;

#[derive(Parser, Debug)]
#[command(about = "Structure-aware differential fuzzing of the compiled policy engine")]
struct Args {
    /// How long to fuzz, in seconds.
    #[arg(long, default_value_t = 60)]
    seconds: u64,
    /// The first seed (cases are seeds in a row, so a run is reproducible).
    #[arg(long, default_value_t = 0)]
    first_seed: u64,
    /// Where findings are written.
    #[arg(long, default_value = "target/fuzz-engine-findings")]
    findings: PathBuf,
    /// Only print the graph of this one seed (ONNX text summary) and compare it.
    #[arg(long)]
    show: Option<u64>,
}

/// xorshift64*: small, seeded, the same everywhere.
struct Rng(u64);

impl Rng {
    fn new(seed: u64) -> Self {
        Self(seed.wrapping_mul(0x9e37_79b9_7f4a_7c15) | 1)
    }
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_f491_4f6c_dd1d)
    }
    fn below(&mut self, n: usize) -> usize {
        (self.next() % n.max(1) as u64) as usize
    }
    fn range(&mut self, low: i64, high: i64) -> i64 {
        low + (self.next() % (high - low + 1) as u64) as i64
    }
    fn chance(&mut self, p: f64) -> bool {
        ((self.next() >> 11) as f64 / (1u64 << 53) as f64) < p
    }
    fn pick<T: Copy>(&mut self, items: &[T]) -> T {
        items[self.below(items.len())]
    }
    fn weights(&mut self, n: usize) -> Vec<f32> {
        (0..n)
            .map(|_| (self.next() >> 40) as f32 / (1u64 << 24) as f32 - 0.5)
            .collect()
    }
}

/// Values that break unchecked size arithmetic.
const HOSTILE: [i64; 9] = [
    -1,
    0,
    (1 << 24) + 1,
    1 << 31,
    (1 << 32) + 1,
    1 << 61,
    i64::MAX,
    i64::MIN,
    -(1 << 40),
];

/// A graph under construction: nodes, constants, and the values whose shapes are known.
struct Builder {
    rng: Rng,
    nodes: Vec<pb::NodeProto>,
    constants: Vec<pb::TensorProto>,
    values: Vec<(String, Vec<usize>)>,
    /// Values of unknown shape (after a hostile attribute): outputs only.
    unknown: Vec<String>,
    counter: usize,
    opset: i64,
}

impl Builder {
    fn name(&mut self, prefix: &str) -> String {
        self.counter += 1;
        format!("{prefix}{}", self.counter)
    }

    /// `value` most of the time; now and then one of the hostile values.
    fn maybe_hostile(&mut self, value: i64) -> i64 {
        if self.rng.chance(0.04) {
            self.rng.pick(&HOSTILE)
        } else {
            value
        }
    }

    fn constant_floats(&mut self, shape: &[usize]) -> String {
        let name = self.name("w");
        let count = shape.iter().product();
        let dims: Vec<i64> = shape.iter().map(|&d| d as i64).collect();
        let values = self.rng.weights(count);
        self.constants.push(floats(&name, &dims, &values));
        name
    }

    fn constant_ints(&mut self, values: &[i64]) -> String {
        let name = self.name("i");
        self.constants
            .push(ints(&name, &[values.len() as i64], values));
        name
    }

    fn push(
        &mut self,
        op: &str,
        inputs: &[&str],
        attributes: &[(&str, Attribute)],
        shape: Option<Vec<usize>>,
    ) {
        let output = self.name("v");
        self.nodes
            .push(node(op, inputs, &[output.as_str()], attributes));
        match shape {
            // Scalars and large values end a chain (the operators below need a rank).
            Some(shape)
                if !shape.is_empty()
                    && shape.iter().all(|&d| d > 0)
                    && shape
                        .iter()
                        .try_fold(1usize, |n, &d| n.checked_mul(d))
                        .is_some_and(|n| n <= 1 << 16) =>
            {
                self.values.push((output, shape))
            }
            _ => self.unknown.push(output),
        }
    }

    /// One random operator on the known values.
    fn step(&mut self) {
        let (input, shape) = self.values[self.rng.below(self.values.len())].clone();
        let rank = shape.len();
        match self.rng.below(15) {
            0 | 1 if rank == 4 => self.conv(&input, &shape),
            2 if rank == 4 => self.max_pool(input, shape),
            3 => self.push("Relu", &[&input], &[], Some(shape)),
            4 => self.flatten(input, shape),
            5 => self.reshape(input, shape),
            6 => self.squeeze_or_unsqueeze(input, shape),
            7 => self.transpose(input, shape),
            8 => self.gather(input, shape),
            9 => self.concat(input, shape),
            10 if rank >= 1 => self.matmul(input, shape),
            11 => self.broadcast_binary(input, shape),
            12 => self.reduce(input, shape),
            13 if shape[..rank.saturating_sub(1)].iter().all(|&d| d == 1) && rank == 3 => {
                self.lstm(&input, shape[2]);
            }
            _ => self.identity_or_cast(input, shape),
        }
    }

    /// A MaxPool with a small (or hostile) kernel and stride.
    fn max_pool(&mut self, input: String, shape: Vec<usize>) {
        let k = self.rng.range(1, 3);
        let s = self.rng.range(1, 3);
        let (k, s) = (self.maybe_hostile(k), self.maybe_hostile(s));
        let out = (k > 0 && s > 0 && shape[2] as i64 >= k && shape[3] as i64 >= k).then(|| {
            let o = |d: usize| ((d as i64 - k) / s + 1) as usize;
            vec![1, shape[1], o(shape[2]), o(shape[3])]
        });
        self.push(
            "MaxPool",
            &[&input],
            &[
                ("kernel_shape", Attribute::Ints(vec![k, k])),
                ("strides", Attribute::Ints(vec![s, s])),
            ],
            out,
        );
    }

    /// A Flatten at a random (or hostile) axis.
    fn flatten(&mut self, input: String, shape: Vec<usize>) {
        let rank = shape.len();
        let axis = self.rng.range(-(rank as i64), rank as i64);
        let axis = self.maybe_hostile(axis);
        let split = if axis < 0 { axis + rank as i64 } else { axis };
        let out = (0..=rank as i64).contains(&split).then(|| {
            let split = split as usize;
            vec![
                shape[..split].iter().product(),
                shape[split..].iter().product(),
            ]
        });
        self.push("Flatten", &[&input], &[("axis", Attribute::Int(axis))], out);
    }

    /// A Reshape to `[first, -1]` or `[-1]`, the target sometimes hostile.
    fn reshape(&mut self, input: String, shape: Vec<usize>) {
        let total: usize = shape.iter().product();
        let first = self.rng.pick(&[1usize, 2, 3, 4]).min(total);
        let target = if total.is_multiple_of(first) {
            vec![first as i64, -1]
        } else {
            vec![-1]
        };
        let target: Vec<i64> = target.into_iter().map(|t| self.maybe_hostile(t)).collect();
        let out = match target[..] {
            [a, -1] if a > 0 => Some(vec![a as usize, total / a as usize]),
            [-1] => Some(vec![total]),
            _ => None,
        };
        let shape_name = self.constant_ints(&target);
        self.push("Reshape", &[&input, &shape_name], &[], out);
    }

    /// An Unsqueeze or a Squeeze at a random (or hostile) axis, its axes an input from opset 13.
    fn squeeze_or_unsqueeze(&mut self, input: String, shape: Vec<usize>) {
        let rank = shape.len();
        let unsqueeze = self.rng.chance(0.5);
        let axis = self.rng.range(-(rank as i64) - 1, rank as i64);
        let axis = self.maybe_hostile(axis);
        let (op, out) = if unsqueeze {
            let r = rank as i64 + 1;
            let a = if axis < 0 { axis + r } else { axis };
            let out = (0..r).contains(&a).then(|| {
                let mut s = shape.clone();
                s.insert(a as usize, 1);
                s
            });
            ("Unsqueeze", out)
        } else {
            let a = if axis < 0 { axis + rank as i64 } else { axis };
            let out = ((0..rank as i64).contains(&a) && shape[a as usize] == 1).then(|| {
                let mut s = shape.clone();
                s.remove(a as usize);
                s
            });
            ("Squeeze", out)
        };
        if self.opset >= 13 {
            let axes = self.constant_ints(&[axis]);
            self.push(op, &[&input, &axes], &[], out);
        } else {
            self.push(op, &[&input], &[("axes", Attribute::Ints(vec![axis]))], out);
        }
    }

    /// A Transpose by a random (sometimes hostile) permutation.
    fn transpose(&mut self, input: String, shape: Vec<usize>) {
        let rank = shape.len();
        let mut perm: Vec<i64> = (0..rank as i64).collect();
        for i in (1..rank).rev() {
            let j = self.rng.below(i + 1);
            perm.swap(i, j);
        }
        if self.rng.chance(0.05) {
            perm[0] = self.rng.pick(&HOSTILE);
        }
        let out = perm
            .iter()
            .map(|&p| usize::try_from(p).ok().and_then(|p| shape.get(p).copied()))
            .collect::<Option<Vec<usize>>>();
        self.push(
            "Transpose",
            &[&input],
            &[("perm", Attribute::Ints(perm))],
            out,
        );
    }

    /// A Gather of one to three random (or hostile) indices on one axis.
    fn gather(&mut self, input: String, shape: Vec<usize>) {
        let rank = shape.len();
        let axis = self.rng.below(rank);
        let dim = shape[axis] as i64;
        let count = 1 + self.rng.below(3);
        let indices: Vec<i64> = (0..count)
            .map(|_| {
                let i = self.rng.range(-dim, dim - 1);
                self.maybe_hostile(i)
            })
            .collect();
        let valid = indices.iter().all(|&i| i >= -dim && i < dim);
        let mut out = shape.clone();
        out[axis] = count;
        let index_name = self.constant_ints(&indices);
        self.push(
            "Gather",
            &[&input, &index_name],
            &[("axis", Attribute::Int(axis as i64))],
            valid.then_some(out),
        );
    }

    /// A Concat of the value with another of its shape (or itself) on one axis.
    fn concat(&mut self, input: String, shape: Vec<usize>) {
        let rank = shape.len();
        let axis = self.rng.below(rank);
        let other = self
            .values
            .iter()
            .find(|(n, s)| *n != input && *s == shape)
            .map(|(n, _)| n.clone());
        let second = other.unwrap_or_else(|| input.clone());
        let mut out = shape.clone();
        out[axis] *= 2;
        self.push(
            "Concat",
            &[&input, &second],
            &[("axis", Attribute::Int(axis as i64))],
            Some(out),
        );
    }

    /// A Gemm, or a MatMul with an Add of a bias after it, on the last axis.
    fn matmul(&mut self, input: String, shape: Vec<usize>) {
        let rank = shape.len();
        let k = shape[rank - 1];
        let n = 1 + self.rng.below(40);
        let w = self.constant_floats(&[k, n]);
        let mut out = shape.clone();
        out[rank - 1] = n;
        if rank == 2 && self.rng.chance(0.5) {
            let bias = self.constant_floats(&[n]);
            let alpha = self.rng.pick(&[1.0f32, 0.5, -1.5]);
            self.push(
                "Gemm",
                &[&input, &w, &bias],
                &[("alpha", Attribute::Float(alpha))],
                Some(out),
            );
        } else {
            self.push("MatMul", &[&input, &w], &[], Some(out.clone()));
            if self.rng.chance(0.6) {
                let product = self.values.last().map(|(n, _)| n.clone());
                if let Some(product) = product {
                    let bias_shape = if self.rng.chance(0.3) {
                        vec![1, n]
                    } else {
                        vec![n]
                    };
                    let bias = self.constant_floats(&bias_shape);
                    let mut sum = out.clone();
                    if bias_shape.len() > sum.len() {
                        sum.insert(0, 1);
                    }
                    self.push("Add", &[&product, &bias], &[], Some(sum));
                }
            }
        }
    }

    /// An Add, Sub, Mul or Div with a constant broadcast to the value.
    fn broadcast_binary(&mut self, input: String, shape: Vec<usize>) {
        let rank = shape.len();
        let op = self.rng.pick(&["Add", "Sub", "Mul", "Div"]);
        // The other operand: the value itself broadcast from a reduced constant.
        let mut other_shape: Vec<usize> = shape
            .iter()
            .map(|&d| if self.rng.chance(0.5) { 1 } else { d })
            .collect();
        let cut = self.rng.below(rank);
        other_shape.drain(..cut);
        let other = self.constant_floats(&other_shape);
        self.push(op, &[&input, &other], &[], Some(shape));
    }

    /// A ReduceMax or ReduceSum over one random (or hostile) axis.
    fn reduce(&mut self, input: String, shape: Vec<usize>) {
        let rank = shape.len();
        let max = self.rng.chance(0.5);
        let op = if max { "ReduceMax" } else { "ReduceSum" };
        let axis = self.rng.range(-(rank as i64), rank as i64 - 1);
        let axis = self.maybe_hostile(axis);
        let keep = self.rng.chance(0.5);
        let a = if axis < 0 { axis + rank as i64 } else { axis };
        let out = (0..rank as i64).contains(&a).then(|| {
            let mut s = shape.clone();
            if keep {
                s[a as usize] = 1;
            } else {
                s.remove(a as usize);
            }
            s
        });
        let as_input = self.opset >= if max { 18 } else { 13 };
        let keepdims = ("keepdims", Attribute::Int(i64::from(keep)));
        if as_input {
            let axes = self.constant_ints(&[axis]);
            self.push(op, &[&input, &axes], &[keepdims], out);
        } else {
            self.push(
                op,
                &[&input],
                &[keepdims, ("axes", Attribute::Ints(vec![axis]))],
                out,
            );
        }
    }

    /// An Identity or a Cast to float.
    fn identity_or_cast(&mut self, input: String, shape: Vec<usize>) {
        let op = self.rng.pick(&["Identity", "Cast"]);
        let attributes = if op == "Cast" {
            vec![("to", Attribute::Int(1))]
        } else {
            vec![]
        };
        self.push(op, &[&input], &attributes, Some(shape));
    }

    fn conv(&mut self, input: &str, shape: &[usize]) {
        let c = shape[1];
        let filters = self.rng.pick(&[1usize, 3, 8, 16, 32]);
        let (kh, kw) = (self.rng.range(1, 5), self.rng.range(1, 5));
        let strides = [self.rng.range(1, 3), self.rng.range(1, 3)];
        let pads = [
            self.rng.range(0, 2),
            self.rng.range(0, 2),
            self.rng.range(0, 2),
            self.rng.range(0, 2),
        ];
        let strides = strides.map(|s| self.maybe_hostile(s));
        let pads = pads.map(|p| self.maybe_hostile(p));
        let w = self.constant_floats(&[filters, c, kh as usize, kw as usize]);
        let b = self.constant_floats(&[filters]);
        let out_dim =
            |size: usize, k: i64, before: i64, after: i64, stride: i64| -> Option<usize> {
                let padded = (size as i64).checked_add(before)?.checked_add(after)?;
                (before >= 0 && after >= 0 && stride > 0 && padded >= k)
                    .then(|| ((padded - k) / stride + 1) as usize)
            };
        let out = out_dim(shape[2], kh, pads[0], pads[2], strides[0])
            .zip(out_dim(shape[3], kw, pads[1], pads[3], strides[1]))
            .map(|(h, w)| vec![1, filters, h, w]);
        self.push(
            "Conv",
            &[input, &w, &b],
            &[
                ("pads", Attribute::Ints(pads.to_vec())),
                ("strides", Attribute::Ints(strides.to_vec())),
            ],
            out,
        );
    }

    fn lstm(&mut self, input: &str, features: usize) {
        let units = self.rng.pick(&[1usize, 4, 16, 64]);
        let gates = 4 * units;
        let w = self.constant_floats(&[1, gates, features]);
        let r = self.constant_floats(&[1, gates, units]);
        let b = self.constant_floats(&[1, 2 * gates]);
        let (h, c) = (self.name("h"), self.name("c"));
        self.nodes.push(node(
            "LSTM",
            &[input, &w, &r, &b],
            &["", h.as_str(), c.as_str()],
            &[("hidden_size", Attribute::Int(units as i64))],
        ));
        self.values.push((h, vec![1, 1, units]));
        self.values.push((c, vec![1, 1, units]));
    }
}

/// The graph and its inputs for one seed.
fn case(seed: u64) -> (pb::ModelProto, Vec<(String, Vec<usize>)>) {
    let mut rng = Rng::new(seed);
    let inputs: Vec<(String, Vec<usize>)> = match rng.below(10) {
        // The CNN manifest's cameras.
        0..=2 => vec![
            ("top".into(), vec![1, 1, 120, 160]),
            ("bottom".into(), vec![1, 1, 60, 80]),
        ],
        // An R-CNN step: features and the LSTM's states.
        3 | 4 => {
            let f = rng.pick(&[8usize, 32, 100]);
            vec![("x".into(), vec![1, 1, f])]
        }
        // Small images.
        5..=7 => {
            let c = rng.pick(&[1usize, 2, 4, 8, 16]);
            vec![("x".into(), vec![1, c, 3 + rng.below(14), 3 + rng.below(14)])]
        }
        // Anything of rank 1 to 4.
        _ => {
            let rank = 1 + rng.below(4);
            vec![("x".into(), (0..rank).map(|_| 1 + rng.below(5)).collect())]
        }
    };
    let opset = rng.pick(&[11i64, 13, 17, 18]);
    let mut builder = Builder {
        rng,
        nodes: Vec::new(),
        constants: Vec::new(),
        values: inputs.clone(),
        unknown: Vec::new(),
        counter: 0,
        opset,
    };
    let steps = 1 + builder.rng.below(7);
    for _ in 0..steps {
        builder.step();
    }
    let mut outputs: Vec<String> = builder.unknown.clone();
    if let Some((last, _)) = builder.values.last() {
        outputs.push(last.clone());
    }
    outputs.dedup();
    let input_refs: Vec<(&str, &[usize])> = inputs
        .iter()
        .map(|(n, s)| (n.as_str(), s.as_slice()))
        .collect();
    let output_refs: Vec<&str> = outputs.iter().map(String::as_str).collect();
    let graph = model(
        opset,
        &input_refs,
        builder.nodes,
        builder.constants,
        &output_refs,
    );
    (graph, inputs)
}

/// Writes a finding where `cargo test` can replay it once moved into the corpus.
fn save(
    findings: &std::path::Path,
    seed: u64,
    graph: &pb::ModelProto,
    inputs: &[(String, Vec<usize>)],
    what: &str,
) {
    use prost::Message;
    let _ = std::fs::create_dir_all(findings);
    let _ = std::fs::write(findings.join(format!("{seed}.onnx")), graph.encode_to_vec());
    // One line an input: its name, then its dimensions.
    let mut text = String::new();
    for (name, shape) in inputs {
        text.push_str(name);
        for dimension in shape {
            text.push_str(&format!(" {dimension}"));
        }
        text.push('\n');
    }
    let _ = std::fs::write(findings.join(format!("{seed}.inputs")), text);
    let _ = std::fs::write(findings.join(format!("{seed}.finding")), what);
}

/// The seed being compared and when it started (milliseconds since the run began): the
/// watchdog's view.
static CURRENT: std::sync::Mutex<Option<(u64, u128)>> = std::sync::Mutex::new(None);

/// Stops the run with a finding when one case takes longer than `limit` or the process holds
/// more than `memory_limit_kb` (a hang or runaway allocation, in tract or the engine).
fn watchdog(started: Instant, limit: Duration, memory_limit_kb: u64, findings: PathBuf) {
    std::thread::spawn(move || {
        loop {
            std::thread::sleep(Duration::from_millis(200));
            let current = *CURRENT
                .lock()
                .unwrap_or_else(std::sync::PoisonError::into_inner);
            let Some((seed, since)) = current else {
                continue;
            };
            let resident_kb = std::fs::read_to_string("/proc/self/status")
                .ok()
                .and_then(|status| {
                    let line = status.lines().find(|l| l.starts_with("VmRSS:"))?;
                    line.split_whitespace().nth(1)?.parse::<u64>().ok()
                })
                .unwrap_or(0);
            let elapsed = started.elapsed().as_millis() - since;
            let what = if elapsed > limit.as_millis() {
                format!("hang: more than {} s", limit.as_secs())
            } else if resident_kb > memory_limit_kb {
                format!("runaway memory: {resident_kb} kB resident")
            } else {
                continue;
            };
            let (graph, inputs) = case(seed);
            println!("seed {seed}: {what}");
            save(&findings, seed, &graph, &inputs, &what);
            std::process::exit(3);
        }
    });
}

/// Whether a comparison is running (its panics are findings, not to be printed twice).
static COMPARING: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);

/// Prints each node of `graph` (`--show`): operator, inputs, outputs, integer attributes.
fn print_graph(graph: &pb::ModelProto) {
    for node in &graph
        .graph
        .as_ref()
        .map(|g| g.node.clone())
        .unwrap_or_default()
    {
        let attributes: Vec<String> = node
            .attribute
            .iter()
            .map(|a| format!("{}={:?}{:?}", a.name, a.i, a.ints))
            .collect();
        println!(
            "{} {:?} -> {:?} {}",
            node.op_type,
            node.input,
            node.output,
            attributes.join(" ")
        );
    }
}

/// The message a panic carried (a `&str` or a `String`), else empty.
fn panic_message(payload: &(dyn std::any::Any + Send)) -> String {
    payload
        .downcast_ref::<&str>()
        .map(|s| (*s).to_owned())
        .or_else(|| payload.downcast_ref::<String>().cloned())
        .unwrap_or_default()
}

fn main() -> anyhow::Result<()> {
    let args = Args::parse();
    // Panics inside a comparison are findings, reported with their message below; any
    // other panic (the generator's own) is printed as usual.
    let default_hook = std::panic::take_hook();
    std::panic::set_hook(Box::new(move |info| {
        if !COMPARING.load(std::sync::atomic::Ordering::Relaxed) {
            default_hook(info);
        }
    }));
    let isas: Vec<Isa> = Isa::available().collect();
    let seeds: Box<dyn Iterator<Item = u64>> = match args.show {
        Some(seed) => Box::new(std::iter::once(seed)),
        None => Box::new(args.first_seed..),
    };
    std::fs::create_dir_all(&args.findings)?;
    let started = Instant::now();
    let limit = Duration::from_secs(args.seconds);
    watchdog(
        started,
        Duration::from_secs(20),
        4 << 20,
        args.findings.clone(),
    );
    let (mut cases, mut both_ran, mut tract_refused, mut engine_refused, mut findings) =
        (0u64, 0u64, 0u64, 0u64, 0u64);
    let mut refusals: std::collections::BTreeMap<String, u64> = Default::default();
    let mut largest = 0.0f32;
    for seed in seeds {
        if args.show.is_none() && started.elapsed() > limit {
            break;
        }
        let (graph, inputs) = case(seed);
        if args.show.is_some() {
            print_graph(&graph);
        }
        std::fs::write(args.findings.join("current-seed"), seed.to_string())?;
        *CURRENT
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner) =
            Some((seed, started.elapsed().as_millis()));
        let input_refs: Vec<(&str, &[usize])> = inputs
            .iter()
            .map(|(n, s)| (n.as_str(), s.as_slice()))
            .collect();
        cases += 1;
        for &isa in &isas {
            COMPARING.store(true, std::sync::atomic::Ordering::Relaxed);
            let outcome = std::panic::catch_unwind(|| compare(&graph, &input_refs, isa, seed, 2));
            COMPARING.store(false, std::sync::atomic::Ordering::Relaxed);
            match outcome {
                Ok(Comparison::Agree { largest_difference }) => {
                    both_ran += 1;
                    largest = largest.max(largest_difference);
                }
                Ok(Comparison::TractRefuses(_)) => {
                    tract_refused += 1;
                    break; // the same on every instruction set
                }
                Ok(Comparison::EngineRefuses(why)) => {
                    engine_refused += 1;
                    let key: String = why
                        .split(':')
                        .next()
                        .unwrap_or("")
                        .chars()
                        .take(40)
                        .collect();
                    *refusals.entry(key).or_default() += 1;
                }
                Ok(Comparison::Disagree(why)) => {
                    findings += 1;
                    println!("seed {seed} ({isa}): disagrees: {why}");
                    save(
                        &args.findings,
                        seed,
                        &graph,
                        &inputs,
                        &format!("{isa}: {why}"),
                    );
                }
                Err(payload) => {
                    findings += 1;
                    let message = panic_message(payload.as_ref());
                    println!("seed {seed} ({isa}): panicked: {message}");
                    save(
                        &args.findings,
                        seed,
                        &graph,
                        &inputs,
                        &format!("{isa}: panic: {message}"),
                    );
                }
            }
        }
    }
    let _ = std::fs::remove_file(args.findings.join("current-seed"));
    let seconds = started.elapsed().as_secs_f64();
    println!(
        "engine fuzz: {cases} graphs in {seconds:.0} s ({:.1} a second; {} instruction sets each), \
         seeds {}..{}: both ran and agreed {both_ran}, tract refused {tract_refused}, the engine refused {engine_refused}, \
         findings {findings}; largest agreed difference {largest:.2e}",
        cases as f64 / seconds,
        isas.len(),
        args.first_seed,
        args.first_seed + cases,
    );
    for (why, count) in refusals {
        println!("  engine refused {count:>6}: {why}");
    }
    if findings > 0 {
        anyhow::bail!("{findings} findings in {}", args.findings.display());
    }
    Ok(())
}
