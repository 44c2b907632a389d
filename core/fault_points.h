// Fault injection: named places in the serving path where a test makes the
// code throw, to reach the exception paths no input can (issue 39: an
// allocation failing inside the request handler on the network thread, in a
// GRI answer's serialization, in a task queue's refill, on the background
// lane). docs/reliability.md "Faults" lists the points and their tests.
//
// A point is armed by a test only; unarmed (always, in binpickd) Hit costs
// one relaxed atomic load. Arming is per process, for a number of hits, and
// each armed hit throws std::bad_alloc: what these places can really throw.
#pragma once

#include <string>

namespace bp::fault {

// Throws std::bad_alloc when `point` is armed (using up one of its hits).
void Hit(const char* point);
// Arms `point` for its next `hits` hits (added to what is left). Any thread.
void Arm(const std::string& point, int hits = 1);
// Hits `point` has left (0: not armed).
int Armed(const std::string& point);
// Disarms every point.
void DisarmAll();

}  // namespace bp::fault
