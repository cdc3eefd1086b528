//! The `build` suite (not implemented yet).

pub(crate) fn run(_args: &[String]) -> Result<crate::Figures, String> {
    Err("the build suite is not implemented yet".into())
}
