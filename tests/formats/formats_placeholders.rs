//! Every text file the formats module writes (JSON, XML, .ct, both scripts) is free of
//! leftover format placeholders such as `{script}`, `{name}`, `{}` or `{x:?}`: a `{{...}}`
//! escape in a format string prints its braces literally.

use t2tf::camera::ParaViewCamera;
use t2tf::formats::write_all;
use t2tf::tf::ControlPoints;
use t2tf::volume::{ByteOrder, ScalarType, SourceFormat};

// The scripts tests' volume: only the file's words matter here, not its values.
use crate::formats_scripts::volume;

/// Placeholders left in `text`: `{` + identifier characters (possibly none) + an optional
/// `:spec` + `}`. JSON's and Python's own braces are followed by a quote, a space or a
/// line break, so they do not match.
fn placeholders(text: &str) -> Vec<String> {
    let mut found = Vec::new();
    for (start, _) in text.match_indices('{') {
        let rest = &text[start + 1..];
        let ident = rest
            .find(|c: char| !(c.is_ascii_alphanumeric() || c == '_'))
            .unwrap_or(rest.len());
        let mut end = ident;
        if rest[end..].starts_with(':') {
            end += rest[end..]
                .find(|c: char| c == '}' || c == '{' || c.is_whitespace() || c == '"')
                .unwrap_or(rest.len() - end);
        }
        if rest[end..].starts_with('}') {
            found.push(text[start..start + end + 2].to_string());
        }
    }
    found
}

#[test]
fn the_checker_finds_placeholders() {
    let text = "# pvpython {script} {} {x:?}\n[{\"Name\": 1}] {name} f'{a}'";
    assert_eq!(
        placeholders(text),
        ["{script}", "{}", "{x:?}", "{name}", "{a}"]
    );
    assert!(placeholders("[{\"a\": {\"b\": []}}]\nd = {\n}\n").is_empty());
}

#[test]
fn written_files_have_no_leftover_placeholders() {
    let cp = ControlPoints::evenly_spaced(vec![0.0, 30.0, 200.0, 10.0], vec![[0.2, 0.4, 0.6]; 4])
        .unwrap();
    let sources = [
        SourceFormat::Raw {
            scalar_type: ScalarType::U16,
            byte_order: ByteOrder::Big,
        },
        SourceFormat::Raw {
            scalar_type: ScalarType::I64,
            byte_order: ByteOrder::Little,
        },
        SourceFormat::Vti {
            array: "density".into(),
        },
        SourceFormat::LegacyVtk {
            array: "scalars".into(),
        },
    ];
    let d = tempfile::tempdir().unwrap();
    let mut checked = 0;
    for (i, format) in sources.into_iter().enumerate() {
        let v = volume(format);
        let name = format!("tf{i}");
        let view = ParaViewCamera::front(&v.geometry, 2.5);
        let files = write_all(d.path(), &name, &cp, &v, &view, [0.1; 3], None).unwrap();
        let scripts = [files.paraview_script.clone(), files.visit_script.clone()];
        for path in [files.json, files.xml, files.ct]
            .into_iter()
            .chain(scripts.into_iter().flatten())
        {
            let text = std::fs::read_to_string(&path).unwrap();
            let left = placeholders(&text);
            assert!(left.is_empty(), "{}: {left:?}", path.display());
            checked += 1;
        }
        // The usage lines name the script's own file.
        let pv = std::fs::read_to_string(files.paraview_script.unwrap()).unwrap();
        assert!(
            pv.contains(&format!("#   pvpython {name}_paraview.py [")),
            "{pv}"
        );
        if let Some(visit) = files.visit_script {
            let visit = std::fs::read_to_string(visit).unwrap();
            assert!(visit.contains(&format!("-s {name}_visit.py [")), "{visit}");
        }
    }
    // 4 × (json, xml, ct, pvpython) + 3 VisIt scripts (none for int64 raw data).
    assert_eq!(checked, 19);
}
