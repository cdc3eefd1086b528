//! The `ooc` suite (not implemented yet).

pub(crate) fn run(_args: &[String]) -> Result<crate::Figures, String> {
    Err("the ooc suite is not implemented yet".into())
}
