pub mod check;

/// DESIGN.md exit codes: 2 for bad input (any `DataError` in the chain), 1 for anything else.
pub fn exit_code(e: &anyhow::Error) -> u8 {
    if e.chain().any(|c| c.is::<i2sdf_data::DataError>()) {
        2
    } else {
        1
    }
}
