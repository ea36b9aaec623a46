//! The model file: a TOML document declaring a model with everything a built-in preset has
//! (states, parameters with nominal values and priors, the drifts and G as expressions, the
//! initial law, the measurements and the simulation defaults). The format is documented in
//! `docs/models.md`, "Models in a file"; [`read`] turns a file's text into a [`Preset`] whose
//! model is an [`ExpressionModel`](super::ExpressionModel).
//!
//! Every error is an [`Error::ModelFile`] naming the file, the line and the column of the
//! problem (inside an expression, the column of the offending character) and what was expected.

use std::ops::Range;
use std::path::Path;
use std::sync::Arc;

use toml::de::{DeTable, DeValue};
use toml::Spanned;

use super::graph::Id;
use super::{name_problem, Builder, Names, Part};
use crate::model::library::{Model, Preset};
use crate::model::observation::{Noise, StateMeasurement};
use crate::model::prior::Prior;
use crate::model::{Dims, Sde};
use crate::{Error, Result};

type Value<'i> = Spanned<DeValue<'i>>;

/// The text of a model file and its name, for positions in messages.
struct Doc<'a> {
    text: &'a str,
    file: &'a str,
}

impl Doc<'_> {
    /// An error at byte `offset` of the text.
    fn error(&self, offset: usize, reason: impl Into<String>) -> Error {
        let offset = offset.min(self.text.len());
        let before = &self.text[..offset];
        let line = before.matches('\n').count() + 1;
        let column = before.rsplit('\n').next().map_or(0, |l| l.chars().count()) + 1;
        Error::ModelFile { file: self.file.to_string(), line, column, reason: reason.into() }
    }

    fn at(&self, span: Range<usize>, reason: impl Into<String>) -> Error {
        self.error(span.start, reason)
    }

    /// The byte offset in the file of byte `offset` of the string value spanning `span`
    /// (after its opening quotes); the string's start when escapes make the two differ.
    fn inside(&self, span: Range<usize>, value: &str, offset: usize) -> usize {
        let raw = &self.text[span.clone()];
        let mut q = if raw.starts_with("\"\"\"") || raw.starts_with("'''") { 3 } else { 1 };
        if q == 3 {
            q += raw[3..].strip_prefix("\r\n").map_or(raw[3..].starts_with('\n') as usize, |_| 2);
        }
        match raw.get(q..) {
            Some(rest) if rest.starts_with(value) => span.start + q + offset,
            _ => span.start,
        }
    }
}

/// A TOML table with the section name it is read as, checking its keys.
struct Section<'a, 'i> {
    name: &'static str,
    table: &'a DeTable<'i>,
    span: Range<usize>,
}

impl<'a, 'i> Section<'a, 'i> {
    fn get(&self, key: &str) -> Option<&'a Value<'i>> {
        self.table.iter().find(|(k, _)| k.get_ref() == key).map(|(_, v)| v)
    }

    /// Errors on a key not in `allowed`.
    fn only(&self, doc: &Doc<'_>, allowed: &[&str]) -> Result<()> {
        for (k, _) in self.table.iter() {
            if !allowed.contains(&k.get_ref().as_ref()) {
                let within = if self.name.is_empty() {
                    "at the top level".to_string()
                } else {
                    format!("in [{}]", self.name)
                };
                return Err(doc.at(
                    k.span(),
                    format!(
                        "unknown key `{}` {within} (expected one of: {})",
                        k.get_ref(),
                        allowed.join(", ")
                    ),
                ));
            }
        }
        Ok(())
    }

    fn required(&self, doc: &Doc<'_>, key: &str, what: &str) -> Result<&'a Value<'i>> {
        self.get(key).ok_or_else(|| {
            let place =
                if self.name.is_empty() { "the file".to_string() } else { format!("[{}]", self.name) };
            doc.at(self.span.clone(), format!("{place} needs `{key}`: {what}"))
        })
    }
}

fn section<'a, 'i>(
    doc: &Doc<'_>,
    top: &Section<'a, 'i>,
    name: &'static str,
    what: &str,
) -> Result<Section<'a, 'i>> {
    let v = top.get(name).ok_or_else(|| doc.error(0, format!("missing table [{name}] ({what})")))?;
    as_section(doc, v, name)
}

fn as_section<'a, 'i>(doc: &Doc<'_>, v: &'a Value<'i>, name: &'static str) -> Result<Section<'a, 'i>> {
    match v.get_ref() {
        DeValue::Table(t) => Ok(Section { name, table: t, span: v.span() }),
        other => Err(doc.at(v.span(), format!("`{name}` must be a table, not a {}", other.type_str()))),
    }
}

fn string<'a>(doc: &Doc<'_>, v: &'a Value<'_>, what: &str) -> Result<&'a str> {
    v.get_ref()
        .as_str()
        .ok_or_else(|| doc.at(v.span(), format!("{what} must be a string, not a {}", v.get_ref().type_str())))
}

fn number(doc: &Doc<'_>, v: &Value<'_>, what: &str) -> Result<f64> {
    let bad = || doc.at(v.span(), format!("{what} must be a number, not a {}", v.get_ref().type_str()));
    match v.get_ref() {
        DeValue::Integer(i) => {
            let s = i.as_str().replace('_', "");
            let (sign, digits) = match s.strip_prefix('-') {
                Some(d) => (-1.0, d.to_string()),
                None => (1.0, s.trim_start_matches('+').to_string()),
            };
            let digits = if i.radix() == 10 { digits.as_str() } else { &digits[2..] };
            i64::from_str_radix(digits, i.radix()).map(|n| sign * n as f64).map_err(|_| bad())
        }
        DeValue::Float(f) => f.as_str().replace('_', "").parse::<f64>().map_err(|_| bad()),
        _ => Err(bad()),
    }
}

fn array<'a, 'i>(doc: &Doc<'_>, v: &'a Value<'i>, what: &str) -> Result<&'a [Value<'i>]> {
    match v.get_ref() {
        DeValue::Array(a) => Ok(a),
        other => Err(doc.at(v.span(), format!("{what} must be an array, not a {}", other.type_str()))),
    }
}

fn strings(doc: &Doc<'_>, v: &Value<'_>, what: &str) -> Result<Vec<Spanned<String>>> {
    array(doc, v, what)?
        .iter()
        .map(|e| Ok(Spanned::new(e.span(), string(doc, e, &format!("each of {what}"))?.to_string())))
        .collect()
}

/// An expression given as a string or a number, with its position.
struct Expr {
    text: String,
    span: Range<usize>,
    quoted: bool,
}

fn expression(doc: &Doc<'_>, v: &Value<'_>, what: &str) -> Result<Expr> {
    match v.get_ref() {
        DeValue::String(s) => Ok(Expr { text: s.to_string(), span: v.span(), quoted: true }),
        DeValue::Integer(_) | DeValue::Float(_) => {
            Ok(Expr { text: doc.text[v.span()].replace('_', ""), span: v.span(), quoted: false })
        }
        other => {
            Err(doc
                .at(v.span(), format!("{what} must be an expression in quotes, not a {}", other.type_str())))
        }
    }
}

/// A parameter's declaration.
struct ParamDecl {
    name: Spanned<String>,
    value: f64,
    prior: Prior,
    estimate: bool,
}

fn parameters(doc: &Doc<'_>, top: &Section<'_, '_>) -> Result<Vec<ParamDecl>> {
    let what = "the parameters θ in order, e.g. `mu = { value = 2.0 }`";
    let sec = section(doc, top, "parameters", what)?;
    let mut entries: Vec<(&Spanned<toml::de::DeString<'_>>, &Value<'_>)> = sec.table.iter().collect();
    entries.sort_by_key(|(k, _)| k.span().start);
    let mut out = Vec::new();
    for (k, v) in entries {
        let name = Spanned::new(k.span(), k.get_ref().to_string());
        let key = format!("parameter `{}`", name.get_ref());
        let decl = match v.get_ref() {
            DeValue::Integer(_) | DeValue::Float(_) => {
                ParamDecl { name, value: number(doc, v, &key)?, prior: Prior::flat(), estimate: false }
            }
            DeValue::Table(_) => {
                let p = as_section(doc, v, "parameters")?;
                p.only(doc, &["value", "prior", "bounds", "estimate"])?;
                let value = number(
                    doc,
                    p.required(doc, "value", "the nominal value")?,
                    &format!("the value of {key}"),
                )?;
                let mut prior = match p.get("prior") {
                    Some(pv) => {
                        let s = string(doc, pv, "a prior")?;
                        Prior::parse(s).map_err(|e| doc.at(pv.span(), format!("prior of {key}: {e}")))?
                    }
                    None => Prior::flat(),
                };
                if let Some(b) = p.get("bounds") {
                    let items = array(doc, b, "bounds")?;
                    if items.len() != 2 {
                        return Err(
                            doc.at(b.span(), "bounds must be [lower, upper] (use -inf or inf for no bound)")
                        );
                    }
                    let (lo, hi) = (number(doc, &items[0], "a bound")?, number(doc, &items[1], "a bound")?);
                    prior = prior.with_bounds(lo, hi);
                    prior.validate().map_err(|e| doc.at(b.span(), format!("bounds of {key}: {e}")))?;
                }
                let estimate = match p.get("estimate") {
                    Some(e) => e
                        .get_ref()
                        .as_bool()
                        .ok_or_else(|| doc.at(e.span(), "`estimate` must be true or false"))?,
                    None => false,
                };
                ParamDecl { name, value, prior, estimate }
            }
            other => {
                return Err(doc
                    .at(v.span(), format!("{key} must be a number or a table, not a {}", other.type_str())))
            }
        };
        if !decl.value.is_finite() {
            return Err(doc.at(v.span(), format!("the value of {key} must be finite")));
        }
        out.push(decl);
    }
    if out.is_empty() {
        return Err(doc.at(sec.span, format!("[parameters] is empty: declare {what}")));
    }
    Ok(out)
}

fn constants(doc: &Doc<'_>, top: &Section<'_, '_>) -> Result<Vec<(Spanned<String>, f64)>> {
    let Some(v) = top.get("constants") else { return Ok(Vec::new()) };
    let sec = as_section(doc, v, "constants")?;
    sec.table
        .iter()
        .map(|(k, v)| {
            let value = number(doc, v, &format!("constant `{}`", k.get_ref()))?;
            Ok((Spanned::new(k.span(), k.get_ref().to_string()), value))
        })
        .collect()
}

/// The declared names: states, parameters, constants; errors at a bad or repeated name and at a
/// name that is both a constant and a parameter.
fn check_declared(
    doc: &Doc<'_>,
    states: &[Spanned<String>],
    params: &[ParamDecl],
    consts: &[(Spanned<String>, f64)],
) -> Result<()> {
    let mut seen: Vec<&str> = Vec::new();
    for n in states.iter().chain(params.iter().map(|p| &p.name)) {
        if let Some(reason) = name_problem(n.get_ref(), &seen) {
            return Err(doc.at(n.span(), reason));
        }
        seen.push(n.get_ref());
    }
    for (c, _) in consts {
        if let Some(p) = params.iter().find(|p| p.name.get_ref() == c.get_ref()) {
            let how = if p.estimate { "estimated" } else { "a parameter" };
            return Err(doc.at(
                p.name.span(),
                format!(
                    "`{}` is both fixed (a constant, line {}) and {how}: declare it in [parameters] \
                     (estimated or not) or in [constants], not both",
                    c.get_ref(),
                    doc.line_of(c.span().start)
                ),
            ));
        }
        if let Some(reason) = name_problem(c.get_ref(), &seen) {
            return Err(doc.at(c.span(), reason));
        }
        seen.push(c.get_ref());
    }
    Ok(())
}

impl Doc<'_> {
    fn line_of(&self, offset: usize) -> usize {
        self.text[..offset.min(self.text.len())].matches('\n').count() + 1
    }

    /// Parses an expression of `part` into the builder; errors at the offending character.
    fn parse(&self, b: &mut Builder, part: Part, e: &Expr) -> Result<Id> {
        b.parse(part, &e.text).map_err(|err| {
            let at = if e.quoted { self.inside(e.span.clone(), &e.text, err.offset) } else { e.span.start };
            self.error(at, format!("{part}: {}", err.message))
        })
    }
}

/// The parsed `[dynamics]`: the roots of f, h and G (column-major), and where G is written.
struct Dynamics {
    f: Vec<Id>,
    h: Vec<Id>,
    g: Vec<Id>,
    g_span: Range<usize>,
}

/// The expressions of `[dynamics]`.
fn dynamics(
    doc: &Doc<'_>,
    top: &Section<'_, '_>,
    b: &mut Builder,
    dims: Dims,
    states: &[Spanned<String>],
) -> Result<Dynamics> {
    let sec = section(doc, top, "dynamics", "the drift, the clean drift and the diffusion")?;
    sec.only(doc, &["drift", "clean_drift", "diffusion"])?;
    let (noisy, clean) = states.split_at(dims.noisy);
    let list = |n: &[Spanned<String>]| n.iter().map(|s| s.get_ref().as_str()).collect::<Vec<_>>().join(", ");
    let components =
        |key: &str, names: &[Spanned<String>], part: fn(usize) -> Part, b: &mut Builder| -> Result<Vec<Id>> {
            let what = format!(
                "one expression per {} state ({})",
                if key == "drift" { "noisy" } else { "clean" },
                list(names)
            );
            let items: &[Value<'_>] = match sec.get(key) {
                Some(v) => array(doc, v, &format!("`{key}`"))?,
                None if names.is_empty() => &[],
                None => return Err(doc.at(sec.span.clone(), format!("[dynamics] needs `{key}`: {what}"))),
            };
            if items.len() != names.len() {
                let at = sec.get(key).map_or(sec.span.clone(), |v| v.span());
                return Err(doc.at(
                    at,
                    format!("`{key}` has {} components, expected {}: {what}", items.len(), names.len()),
                ));
            }
            items.iter().enumerate().map(|(i, v)| doc.parse(b, part(i), &expression(doc, v, key)?)).collect()
        };
    let f = components("drift", noisy, Part::Drift, b)?;
    let h = components("clean_drift", clean, Part::CleanDrift, b)?;
    let gv = sec.required(
        doc,
        "diffusion",
        "G(θ): a scalar expression (G = g I), a list (the diagonal) or a list of rows",
    )?;
    let n = dims.noisy;
    let shape = format!("G must be square, {n} × {n} (one row and column per noisy state {})", list(noisy));
    let mut g: Vec<Option<Id>> = vec![None; n * n];
    match gv.get_ref() {
        DeValue::Array(rows) if rows.iter().any(|r| r.get_ref().as_array().is_some()) => {
            if rows.len() != n {
                return Err(doc.at(gv.span(), format!("{shape}: got {} rows", rows.len())));
            }
            for (r, row) in rows.iter().enumerate() {
                let cols = array(doc, row, "a row of G")?;
                if cols.len() != n {
                    return Err(
                        doc.at(row.span(), format!("{shape}: row {} has {} entries", r + 1, cols.len()))
                    );
                }
                for (c, v) in cols.iter().enumerate() {
                    g[r + c * n] =
                        Some(doc.parse(b, Part::Diffusion(r, c), &expression(doc, v, "an entry of G")?)?);
                }
            }
        }
        DeValue::Array(diag) => {
            if diag.len() != n {
                return Err(doc.at(gv.span(), format!("{shape}: a diagonal of {} entries", diag.len())));
            }
            for (i, v) in diag.iter().enumerate() {
                g[i + i * n] =
                    Some(doc.parse(b, Part::Diffusion(i, i), &expression(doc, v, "an entry of G")?)?);
            }
        }
        _ => {
            let id = doc.parse(b, Part::Diffusion(0, 0), &expression(doc, gv, "diffusion")?)?;
            (0..n).for_each(|i| g[i + i * n] = Some(id));
        }
    }
    let zero = b.zero();
    Ok(Dynamics { f, h, g: g.into_iter().map(|e| e.unwrap_or(zero)).collect(), g_span: gv.span() })
}

/// The prior of each initial state, from `[initial]`.
fn initial(doc: &Doc<'_>, top: &Section<'_, '_>, states: &[Spanned<String>]) -> Result<Vec<Prior>> {
    let sec = section(doc, top, "initial", "the prior of each initial state, e.g. `u = \"normal:0,1\"`")?;
    let names: Vec<&str> = states.iter().map(|s| s.get_ref().as_str()).collect();
    sec.only(doc, &names)?;
    states
        .iter()
        .map(|s| {
            let v = sec.required(doc, s.get_ref(), "the prior of this initial state, e.g. \"normal:0,1\"")?;
            let text = string(doc, v, "a prior")?;
            Prior::parse(text)
                .map_err(|e| doc.at(v.span(), format!("prior of the initial state `{}`: {e}", s.get_ref())))
        })
        .collect()
}

/// The measurements and their times, from `[measurements]`.
fn measurements(
    doc: &Doc<'_>,
    top: &Section<'_, '_>,
    states: &[Spanned<String>],
    params: &[String],
) -> Result<(StateMeasurement, f64, f64)> {
    let sec = section(doc, top, "measurements", "the measured states, the likelihood and the sampling")?;
    sec.only(doc, &["states", "names", "likelihood", "every", "first"])?;
    let sv = sec.required(doc, "states", "the measured states, e.g. [\"u\"]")?;
    let measured = strings(doc, sv, "`states`")?;
    if measured.is_empty() {
        return Err(doc.at(sv.span(), "`states` must name at least one measured state"));
    }
    let known: Vec<&str> = states.iter().map(|s| s.get_ref().as_str()).collect();
    let indices = measured
        .iter()
        .map(|m| {
            known.iter().position(|k| k == m.get_ref()).ok_or_else(|| {
                doc.at(m.span(), format!("unknown state `{}` (known: {})", m.get_ref(), known.join(", ")))
            })
        })
        .collect::<Result<Vec<usize>>>()?;
    let names: Vec<String> = match sec.get("names") {
        Some(nv) => {
            let names = strings(doc, nv, "`names`")?;
            if names.len() != measured.len() {
                return Err(doc.at(
                    nv.span(),
                    format!("the likelihood has {} outputs (`states`) but `names` has {}: give one name per output", measured.len(), names.len()),
                ));
            }
            names.into_iter().map(Spanned::into_inner).collect()
        }
        None if measured.len() == 1 => vec!["y".into()],
        None => (1..=measured.len()).map(|k| format!("y{k}")).collect(),
    };
    let lv = sec.required(doc, "likelihood", "e.g. \"gaussian:sigma=0.1\" or \"gaussian:sigma=sigma_y\"")?;
    let spec = string(doc, lv, "the likelihood")?;
    let noise = Noise::parse(spec, params).map_err(|e| doc.at(lv.span(), format!("likelihood: {e}")))?;
    let every = number(doc, sec.required(doc, "every", "the time between measurements")?, "`every`")?;
    let first = match sec.get("first") {
        Some(v) => number(doc, v, "`first`")?,
        None => 0.0,
    };
    Ok((StateMeasurement::new(indices, names, noise), every, first))
}

/// Reads a model file's text (`file` names it in messages) into a preset.
pub fn read(text: &str, file: &str) -> Result<Preset> {
    let doc = Doc { text, file };
    if text.trim().is_empty() {
        return Err(doc.error(0, "empty model file: expected [states], [parameters], [dynamics], [initial], [measurements] and [simulation] (see docs/models.md)"));
    }
    let parsed = DeTable::parse(text).map_err(|e| {
        let at = e.span().map_or(0, |s| s.start);
        doc.error(at, format!("TOML syntax: {}", e.message().trim()))
    })?;
    let top = Section { name: "", table: parsed.get_ref(), span: 0..0 };
    top.only(
        &doc,
        &[
            "name",
            "description",
            "source",
            "states",
            "parameters",
            "constants",
            "dynamics",
            "initial",
            "measurements",
            "simulation",
        ],
    )?;
    let text_of = |key: &str| -> Result<Option<String>> {
        top.get(key).map(|v| string(&doc, v, &format!("`{key}`")).map(String::from)).transpose()
    };
    let name = text_of("name")?.unwrap_or_else(|| default_name(file));
    let description = text_of("description")?.unwrap_or_default();
    let source = text_of("source")?.unwrap_or_else(|| format!("model file {file}"));

    let st = section(&doc, &top, "states", "the names of the noisy and clean states")?;
    st.only(&doc, &["noisy", "clean"])?;
    let noisy =
        strings(&doc, st.required(&doc, "noisy", "the names of the noisy states, e.g. [\"x\"]")?, "`noisy`")?;
    if noisy.is_empty() {
        return Err(doc.at(st.span.clone(), "a model needs at least one noisy state"));
    }
    let clean = match st.get("clean") {
        Some(v) => strings(&doc, v, "`clean`")?,
        None => Vec::new(),
    };
    let params = parameters(&doc, &top)?;
    let consts = constants(&doc, &top)?;
    let states: Vec<Spanned<String>> = noisy.iter().chain(&clean).cloned().collect();
    check_declared(&doc, &states, &params, &consts)?;
    let dims = Dims { noisy: noisy.len(), clean: clean.len(), params: params.len() };
    let own = |v: &[Spanned<String>]| v.iter().map(|s| s.get_ref().clone()).collect::<Vec<_>>();
    let param_names: Vec<String> = params.iter().map(|p| p.name.get_ref().clone()).collect();
    let const_values: Vec<(String, f64)> = consts.iter().map(|(n, v)| (n.get_ref().clone(), *v)).collect();
    let mut b = Builder::new(Names::new(&own(&noisy), &own(&clean), &param_names, &const_values), dims);
    let Dynamics { f, h, g, g_span } = dynamics(&doc, &top, &mut b, dims, &states)?;
    let model = b.finish(&f, &h, &g);
    let priors = initial(&doc, &top, &states)?;
    let (observation, every, first) = measurements(&doc, &top, &states, &param_names)?;
    let sim = section(&doc, &top, "simulation", "`t_end` and `dt`, the horizon and step of the simulator")?;
    sim.only(&doc, &["t_end", "dt"])?;
    let t_end = number(&doc, sim.required(&doc, "t_end", "the final time")?, "`t_end`")?;
    let dt = number(&doc, sim.required(&doc, "dt", "the simulation step")?, "`dt`")?;
    let theta: Vec<f64> = params.iter().map(|p| p.value).collect();
    if let Err(e) = model.diffusion_matrix(&theta) {
        return Err(doc.at(g_span, format!("G must be invertible at the nominal parameters: {e}")));
    }
    let mut x0_prior = priors;
    let z0_prior = x0_prior.split_off(dims.noisy);
    let preset = Preset {
        name,
        description,
        source,
        model: Model::Expression(Arc::new(model)),
        theta,
        theta_prior: params.iter().map(|p| p.prior).collect(),
        estimate: params.iter().map(|p| p.estimate).collect(),
        x0_prior,
        z0_prior,
        observation,
        t_end,
        dt,
        first_sample: first,
        sample_every: every,
    };
    preset.validate().map_err(|e| doc.error(0, format!("the declared model is inconsistent: {e}")))?;
    Ok(preset)
}

/// The file's stem, the name of a model file that declares none.
fn default_name(file: &str) -> String {
    Path::new(file).file_stem().map_or_else(|| "model".to_string(), |s| s.to_string_lossy().into_owned())
}

/// Reads the model file at `path` into a preset (see [`read`]).
pub fn read_path(path: &Path) -> Result<Preset> {
    let text =
        std::fs::read_to_string(path).map_err(|source| Error::Io { path: path.to_path_buf(), source })?;
    read(&text, &path.display().to_string())
}

impl Preset {
    /// The preset declared by a model file's text; `file` names it in error messages (see
    /// `docs/models.md`, "Models in a file"). Errors: [`Error::ModelFile`] with the line and
    /// column of the problem.
    pub fn from_toml_str(text: &str, file: &str) -> Result<Preset> {
        read(text, file)
    }

    /// The preset declared by the model file at `path`. Errors: [`Error::Io`] when it cannot be
    /// read, [`Error::ModelFile`] with the line and column of a problem in it.
    pub fn from_path(path: impl AsRef<Path>) -> Result<Preset> {
        read_path(path.as_ref())
    }
}
