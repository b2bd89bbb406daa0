//! The names of the enums a flag takes, from clap's [`clap::ValueEnum`]:
//! what `--builder`, `--intersector` and the rest accept is what reports
//! print, with no second list to keep in step.

use std::collections::HashSet;
use std::sync::{Mutex, OnceLock};

use clap::ValueEnum;

/// `name` as a `&'static str`: each distinct name is kept once for the life
/// of the process (names made from a few enums and specs: a bounded set).
pub fn intern(name: &str) -> &'static str {
    static NAMES: Mutex<Option<HashSet<&'static str>>> = Mutex::new(None);
    let mut names = NAMES.lock().unwrap_or_else(|e| e.into_inner());
    let names = names.get_or_insert_with(HashSet::new);
    if let Some(&kept) = names.get(name) {
        return kept;
    }
    let kept: &'static str = Box::leak(name.to_string().into_boxed_str());
    names.insert(kept);
    kept
}

/// `value`'s name as its flag takes it, made once per type (`cache`, one
/// per enum).
pub fn value_name<T: ValueEnum + PartialEq>(
    cache: &'static OnceLock<Vec<&'static str>>,
    value: &T,
) -> &'static str {
    let names = cache.get_or_init(|| {
        T::value_variants()
            .iter()
            .map(|v| {
                let name = v
                    .to_possible_value()
                    .expect("no variant of a named enum is skipped");
                intern(name.get_name())
            })
            .collect()
    });
    let i = T::value_variants()
        .iter()
        .position(|v| v == value)
        .expect("every value is one of its enum's variants");
    names[i]
}

/// Gives each enum a `name()`: its name as clap's `ValueEnum` spells it.
macro_rules! value_names {
    ($($t:ty),* $(,)?) => {$(
        impl $t {
            /// The name its flag takes (clap's `ValueEnum`), which reports print.
            pub fn name(self) -> &'static str {
                static NAMES: ::std::sync::OnceLock<Vec<&'static str>> =
                    ::std::sync::OnceLock::new();
                $crate::names::value_name(&NAMES, &self)
            }
        }
    )*};
}
pub(crate) use value_names;

value_names!(
    crate::accel::BackendKind,
    crate::accel::bvh::BuilderKind,
    crate::accel::embree::Quality,
    crate::geometry::Intersector,
    crate::geometry::OffsetStrategy,
    crate::render::Schedule,
    crate::measure::validate::RaySet,
);

#[cfg(test)]
mod tests {
    use crate::accel::bvh::BuilderKind;
    use crate::accel::BackendKind;
    use crate::geometry::{Intersector, OffsetStrategy};
    use crate::measure::validate::RaySet;
    use crate::render::Schedule;

    #[test]
    fn names_are_the_flags() {
        let names = |v: &[&str]| v.join(" ");
        assert_eq!(
            names(&BackendKind::ALL.map(BackendKind::name)),
            "naive bvh embree tinybvh obvhs bvh-crate"
        );
        assert_eq!(
            names(&BuilderKind::ALL.map(BuilderKind::name)),
            "median lbvh sah sbvh embree-low embree-medium embree-high"
        );
        assert_eq!(Intersector::Watertight.name(), "watertight");
        assert_eq!(
            names(&OffsetStrategy::ALL.map(OffsetStrategy::name)),
            "none fixed scaled tmin ulp bounded"
        );
        assert_eq!(
            names(&Schedule::ALL.map(Schedule::name)),
            "serial rows tiles rayon"
        );
        assert_eq!(
            names(&RaySet::ALL.map(RaySet::name)),
            "primary shadow ao diffuse random"
        );
        assert_eq!(crate::accel::embree::Quality::High.name(), "high");
        assert_eq!(RaySet::Edges.name(), "edges");
        // The lists the code walks are clap's.
        use clap::ValueEnum;
        assert_eq!(BackendKind::ALL, BackendKind::value_variants());
        assert_eq!(BuilderKind::ALL, BuilderKind::value_variants());
        assert_eq!(Schedule::ALL, Schedule::value_variants());
        assert_eq!(OffsetStrategy::ALL, OffsetStrategy::value_variants());
    }
}
