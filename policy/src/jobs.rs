//! Several trainings (or evaluations) at a time on a fixed number of threads: `mars benchmark`, `mars curve`,
//! `mars ablate` all hand their work list here.

use std::sync::Mutex;

/// Runs `jobs` workers over `items`, collecting each result; the first error stops the run.
pub fn parallel<T: Sync, R: Send>(
    items: &[T],
    jobs: usize,
    f: &(dyn Fn(&T) -> anyhow::Result<R> + Sync),
) -> anyhow::Result<Vec<R>> {
    let next = Mutex::new(0usize);
    let results = Mutex::new(Vec::new());
    std::thread::scope(|scope| -> anyhow::Result<()> {
        let workers: Vec<_> = (0..jobs.clamp(1, items.len().max(1)))
            .map(|_| {
                scope.spawn(|| -> anyhow::Result<()> {
                    loop {
                        let i = {
                            let mut n = next.lock().unwrap_or_else(|e| e.into_inner());
                            *n += 1;
                            *n - 1
                        };
                        let Some(item) = items.get(i) else { break };
                        let r = f(item)?;
                        results.lock().unwrap_or_else(|e| e.into_inner()).push((i, r));
                    }
                    Ok(())
                })
            })
            .collect();
        for w in workers {
            w.join().map_err(|_| anyhow::anyhow!("a worker panicked"))??;
        }
        Ok(())
    })?;
    let mut r = results.into_inner().unwrap_or_else(|e| e.into_inner());
    r.sort_by_key(|(i, _)| *i);
    Ok(r.into_iter().map(|(_, r)| r).collect())
}
