//! A network of its own for a test: a Linux network namespace joined to this one by a veth pair, with loss and a
//! partition applied by the kernel's nftables, so a robot here and an inference host in the namespace talk over a
//! real IP link that no one else's traffic shares. Made by [`NetNs::create`], removed on drop.
//!
//! Why nftables and not `tc netem` (delay, jitter, loss in one qdisc): this VM's kernel is built without netem
//! (`CONFIG_NET_SCH_NETEM` unset), while nftables' `numgen random` drops a share of packets and a plain `drop` rule
//! partitions. Delay stays with [`crate::shaped_link::ShapedLink`], in user space. Needs root, `ip` (iproute2) and
//! `nft` (Debian's `nftables`, which `.ci/system-packages` installs).
//!
//! The rules sit in this namespace's `input` and `output` hooks, on the veth's name: they see only this link.

use std::process::Command;

use anyhow::Context;

/// A namespace, its veth pair and its nftables table; all removed on drop.
pub struct NetNs {
    /// The namespace's name (`ip netns exec <name> …`).
    pub name: String,
    /// The veth end in this namespace, and the addresses of both ends.
    veth: String,
    pub here_ip: String,
    pub there_ip: String,
    table: String,
}

impl NetNs {
    /// Makes `mars-<tag>` with a /30 link from here (`here_ip`) to it (`there_ip`), both ends up, and an empty
    /// nftables table for the link's rules. `tag` must be short (interface names hold 15 bytes) and unique on
    /// this machine (e.g. the test's pid).
    pub fn create(tag: u32) -> anyhow::Result<Self> {
        // SAFETY: geteuid(2) reads the process's credentials; it cannot fail.
        let euid = unsafe { libc::geteuid() };
        anyhow::ensure!(euid == 0, "a network namespace needs root (this test builds its own network with ip and nft)");
        // 10.213.0.0/16 in /30 blocks, by tag: no clash between the tests of one run.
        let block = (tag % 16_384) * 4;
        let (a, b) = (block / 256, block % 256);
        let ns = NetNs {
            name: format!("mars-{tag}"),
            veth: format!("mva{tag}"),
            here_ip: format!("10.213.{a}.{}", b + 1),
            there_ip: format!("10.213.{a}.{}", b + 2),
            table: format!("mars{tag}"),
        };
        let peer = format!("mvb{tag}");
        run("ip", &["netns", "add", &ns.name])?;
        run("ip", &["link", "add", &ns.veth, "type", "veth", "peer", "name", &peer])?;
        run("ip", &["link", "set", &peer, "netns", &ns.name])?;
        run("ip", &["addr", "add", &format!("{}/30", ns.here_ip), "dev", &ns.veth])?;
        run("ip", &["link", "set", &ns.veth, "up"])?;
        let inside = |args: &[&str]| run("ip", &[&["netns", "exec", ns.name.as_str(), "ip"][..], args].concat());
        inside(&["addr", "add", &format!("{}/30", ns.there_ip), "dev", &peer])?;
        inside(&["link", "set", &peer, "up"])?;
        inside(&["link", "set", "lo", "up"])?;
        ns.apply(0, false)?;
        Ok(ns)
    }

    /// `program` run inside the namespace (`ip netns exec` execs it: the child's pid is the program's).
    pub fn command(&self, program: &std::path::Path) -> Command {
        let mut cmd = Command::new("ip");
        cmd.args(["netns", "exec", &self.name]).arg(program);
        cmd
    }

    /// Drops `loss_percent` % of the link's packets each way at random, and with `partitioned` all of them. Replaces
    /// the rules in force.
    pub fn apply(&self, loss_percent: u32, partitioned: bool) -> anyhow::Result<()> {
        anyhow::ensure!(loss_percent <= 100, "loss of {loss_percent} %");
        let mut rules = format!("table inet {t}\ndelete table inet {t}\ntable inet {t} {{\n", t = self.table);
        for (chain, dir) in [("input", "iifname"), ("output", "oifname")] {
            rules += &format!("  chain {chain} {{\n    type filter hook {chain} priority 0; policy accept;\n");
            if partitioned {
                rules += &format!("    {dir} \"{}\" drop\n", self.veth);
            } else if loss_percent > 0 {
                rules += &format!("    {dir} \"{}\" numgen random mod 100 < {loss_percent} drop\n", self.veth);
            }
            rules += "  }\n";
        }
        rules += "}\n";
        nft(&rules)
    }
}

impl Drop for NetNs {
    fn drop(&mut self) {
        // Deleting the namespace deletes the veth pair with it.
        let _ = nft(&format!("table inet {t}\ndelete table inet {t}\n", t = self.table));
        let _ = run("ip", &["netns", "del", &self.name]);
    }
}

/// Runs a command to its end; an error with its stderr when it fails.
fn run(program: &str, args: &[&str]) -> anyhow::Result<()> {
    let out = Command::new(program).args(args).output().with_context(|| format!("running {program}"))?;
    anyhow::ensure!(
        out.status.success(),
        "{program} {}: {}",
        args.join(" "),
        String::from_utf8_lossy(&out.stderr).trim()
    );
    Ok(())
}

/// Loads an nftables ruleset (`nft -f -`), atomically.
fn nft(rules: &str) -> anyhow::Result<()> {
    use std::io::Write as _;
    let mut child = Command::new("nft")
        .args(["-f", "-"])
        .stdin(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .context("running nft (Debian's nftables)")?;
    child.stdin.take().expect("piped").write_all(rules.as_bytes())?;
    let out = child.wait_with_output()?;
    anyhow::ensure!(out.status.success(), "nft: {}\n{rules}", String::from_utf8_lossy(&out.stderr).trim());
    Ok(())
}
