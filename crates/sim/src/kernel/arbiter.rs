//! An N-way round-robin arbiter that skips requesters with nothing to offer or whose
//! request is refused downstream.

use serde::Serialize;

/// A requester's answer when the arbiter offers it the grant.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Offer {
    /// It had a request and the request went through.
    Granted,
    /// It had nothing to send.
    Nothing,
    /// It had a request but the destination refused it (full); the grant moves on.
    Refused,
}

/// Round-robin arbitration among `n` requesters with at most `max_grants` grants per call
/// (per cycle). Each call offers the grant to every requester at most once, starting after
/// the last winner of the previous call that granted anything.
#[derive(Clone, Debug)]
pub struct RoundRobin {
    next: usize,
    max_grants: usize,
    grants: Vec<u64>,
    refusals: Vec<u64>,
    /// Requester `i`'s last offer was refused (a refusal episode is open).
    refusing: Vec<bool>,
}

impl RoundRobin {
    /// An arbiter for `n` requesters granting at most `max_grants` per call.
    ///
    /// # Errors
    /// `n` or `max_grants` of zero.
    pub fn new(n: usize, max_grants: usize) -> Result<Self, super::ConfigError> {
        if n == 0 || max_grants == 0 {
            return Err(super::ConfigError::new(
                "round-robin arbiter",
                "needs at least one requester and one grant per cycle",
            ));
        }
        Ok(Self {
            next: 0,
            max_grants,
            grants: vec![0; n],
            refusals: vec![0; n],
            refusing: vec![false; n],
        })
    }

    /// Offers the grant in round-robin order: `try_requester(i)` tries requester `i`'s
    /// request. Returns the number granted.
    #[inline]
    pub fn arbitrate(&mut self, mut try_requester: impl FnMut(usize) -> Offer) -> usize {
        let n = self.grants.len();
        let mut granted = 0;
        let mut i = self.next;
        let mut last = None;
        for _ in 0..n {
            match try_requester(i) {
                Offer::Granted => {
                    self.refusing[i] = false;
                    self.grants[i] += 1;
                    granted += 1;
                    last = Some(i);
                    if granted == self.max_grants {
                        break;
                    }
                }
                Offer::Refused => {
                    self.refusals[i] += !self.refusing[i] as u64;
                    self.refusing[i] = true;
                }
                Offer::Nothing => self.refusing[i] = false,
            }
            i += 1;
            if i == n {
                i = 0;
            }
        }
        if let Some(w) = last {
            self.next = if w + 1 == n { 0 } else { w + 1 };
        }
        granted
    }

    /// Requester the next call starts with.
    pub fn next_first(&self) -> usize {
        self.next
    }

    /// Statistics so far.
    pub fn stats(&self) -> ArbiterStats {
        ArbiterStats {
            grants: self.grants.clone(),
            refusals: self.refusals.clone(),
        }
    }
}

/// Counts of a [`RoundRobin`] arbiter.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize)]
pub struct ArbiterStats {
    /// Grants per requester.
    pub grants: Vec<u64>,
    /// Refusal episodes per requester: offers whose request the destination refused,
    /// counting consecutive refused offers once (so the figure does not depend on how
    /// often a stalled arbiter is stepped).
    pub refusals: Vec<u64>,
}

impl ArbiterStats {
    /// All grants.
    pub fn total_grants(&self) -> u64 {
        self.grants.iter().sum()
    }

    /// All refusals.
    pub fn total_refusals(&self) -> u64 {
        self.refusals.iter().sum()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn grants_rotate_and_skip_idle_and_refused_requesters() {
        let mut a = RoundRobin::new(4, 1).unwrap();
        // Requester 3 is refused every time: one episode.
        let mut order = Vec::new();
        for _ in 0..8 {
            a.arbitrate(|i| {
                if i == 2 {
                    Offer::Nothing
                } else if i == 3 {
                    Offer::Refused
                } else {
                    order.push(i);
                    Offer::Granted
                }
            });
        }
        assert_eq!(order, vec![0, 1, 0, 1, 0, 1, 0, 1]);
        let s = a.stats();
        assert_eq!(s.grants, vec![4, 4, 0, 0]);
        assert_eq!(s.refusals, vec![0, 0, 0, 1]);
        // An accepted offer ends the episode.
        a.arbitrate(|i| {
            if i == 3 {
                Offer::Granted
            } else {
                Offer::Nothing
            }
        });
        a.arbitrate(|i| {
            if i == 3 {
                Offer::Refused
            } else {
                Offer::Nothing
            }
        });
        assert_eq!(a.stats().refusals, vec![0, 0, 0, 2]);
    }

    #[test]
    fn at_most_k_grants_per_call_and_each_requester_once() {
        let mut a = RoundRobin::new(5, 2).unwrap();
        let mut seen = Vec::new();
        assert_eq!(
            a.arbitrate(|i| {
                seen.push(i);
                Offer::Granted
            }),
            2
        );
        assert_eq!(seen, vec![0, 1]);
        assert_eq!(a.next_first(), 2);
        seen.clear();
        assert_eq!(
            a.arbitrate(|i| {
                seen.push(i);
                if i == 4 {
                    Offer::Granted
                } else {
                    Offer::Nothing
                }
            }),
            1
        );
        assert_eq!(seen, vec![2, 3, 4, 0, 1]);
        assert_eq!(a.next_first(), 0);
        // Nothing granted: the pointer stays.
        a.arbitrate(|_| Offer::Nothing);
        assert_eq!(a.next_first(), 0);
        assert!(RoundRobin::new(0, 1).is_err() && RoundRobin::new(1, 0).is_err());
    }
}
