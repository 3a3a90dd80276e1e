//! Service processes for the tests: started from the built `outlet`, ended
//! however the test ends.

use std::process::{Child, Command, Stdio};

pub struct Services(pub Vec<Child>);

impl Services {
    /// Starts `outlet serve ...` once per argument list.
    pub fn start(args: &[&[&str]]) -> std::io::Result<Self> {
        let mut children = Vec::new();
        for a in args {
            children.push(
                Command::new(env!("CARGO_BIN_EXE_outlet"))
                    .arg("serve")
                    .args(*a)
                    .stdout(Stdio::null())
                    .stderr(Stdio::null())
                    .spawn()?,
            );
        }
        Ok(Self(children))
    }

    /// True while every service is running.
    pub fn all_running(&mut self) -> bool {
        self.0.iter_mut().all(|c| matches!(c.try_wait(), Ok(None)))
    }
}

impl Drop for Services {
    fn drop(&mut self) {
        for c in &mut self.0 {
            let _ = c.kill();
            let _ = c.wait();
        }
    }
}
