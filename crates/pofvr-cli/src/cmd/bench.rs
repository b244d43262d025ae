use anyhow::Result;

use crate::args::BenchRenderArgs;
use crate::progress::Ui;

pub(crate) fn render(_a: &BenchRenderArgs, _ui: &Ui) -> Result<()> {
    anyhow::bail!("bench render is being written")
}
