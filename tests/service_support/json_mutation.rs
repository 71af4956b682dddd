//! Random edits of a JSON document, for the parser properties and the HTTP fuzz harness: members at
//! any depth replaced, removed or emptied.

use rand::Rng;
use serde_json::Value;

/// Makes `edits` (a count drawn from the range) edits of `v`: each walks a random JSON pointer
/// into `v` (descending with probability `descend` at each level), then removes a member of the
/// object or the last element of the array found there (probability 0.3) or replaces it with
/// `replacement(rng)`.
pub fn mutate<R: Rng>(
    rng: &mut R,
    v: &mut Value,
    edits: std::ops::RangeInclusive<u32>,
    descend: f64,
    mut replacement: impl FnMut(&mut R) -> Value,
) {
    for _ in 0..rng.random_range(edits) {
        // A random JSON pointer into `v`, walked without mutating it.
        let (mut pointer, mut node) = (String::new(), &*v);
        loop {
            let next = match node {
                Value::Object(m) if !m.is_empty() && rng.random_bool(descend) => {
                    let (k, n) = m.iter().nth(rng.random_range(0..m.len())).unwrap();
                    Some((k.replace('~', "~0").replace('/', "~1"), n))
                }
                Value::Array(a) if !a.is_empty() && rng.random_bool(descend) => {
                    let i = rng.random_range(0..a.len());
                    Some((i.to_string(), &a[i]))
                }
                _ => None,
            };
            match next {
                Some((k, n)) => {
                    pointer = format!("{pointer}/{k}");
                    node = n;
                }
                None => break,
            }
        }
        let replacement = replacement(rng);
        let remove = rng.random_bool(0.3);
        let Some(target) = v.pointer_mut(&pointer) else {
            continue;
        };
        match target {
            Value::Object(m) if remove && !m.is_empty() => {
                let k = m.keys().next().unwrap().clone();
                m.remove(&k);
            }
            Value::Array(a) if remove => {
                a.pop();
            }
            _ => *target = replacement,
        }
    }
}
