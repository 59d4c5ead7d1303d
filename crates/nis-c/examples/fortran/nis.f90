!> nis.f90: Fortran bindings of the nis C ABI (crates/nis-c/include/nis.h) through iso_c_binding.
!>
!> Strings passed in end with c_null_char; an integrator is a type(c_ptr); the integrand is a
!> bind(c) function with the interface nis_integrand below, passed as c_funloc(f). Points arrive
!> column-major as x(dim, n) (the C side's row-major n x dim), values go to out(n), or out(k, n)
!> for k components. By default the library never calls the integrand from two threads at once,
!> so integrands with SAVE state are safe. Status codes are those of nis.h.
module nis
  use, intrinsic :: iso_c_binding
  implicit none
  private

  integer(c_int), parameter, public :: NIS_OK = 0, NIS_ERR_NULL_POINTER = 1, &
       NIS_ERR_INVALID_ARGUMENT = 2, NIS_ERR_CONFIG = 3, NIS_ERR_CALLBACK = 4, &
       NIS_ERR_NON_FINITE = 5, NIS_ERR_FILE = 6, NIS_ERR_UNSUPPORTED = 7, &
       NIS_ERR_NO_RESULT = 8, NIS_ERR_PANIC = 9
  !> Why a run to a precision target stopped (nis_result_stop).
  integer(c_int), parameter, public :: NIS_STOP_NONE = 0, NIS_STOP_TARGET = 1, &
       NIS_STOP_MAX_EVALS = 2, NIS_STOP_MAX_SECONDS = 3
  !> Whose sampler made the last estimate (nis_result_answered_by).
  integer(c_int), parameter, public :: NIS_ANSWERED_BY_OWN = 0, NIS_ANSWERED_BY_VEGAS = 1

  !> A channel (nis_channel in nis.h): its sample and density callbacks (bind(c) functions with
  !> the interface nis_channel_fn below, as c_funloc), a user pointer, an a-priori weight
  !> (0: 1) and an optional enhancement callback (c_null_funptr: none).
  type, bind(c), public :: nis_channel
     type(c_funptr) :: sample, density
     type(c_ptr) :: user
     real(c_double) :: prior
     type(c_funptr) :: enhancement
  end type nis_channel

  !> The summary of a result (nis_result in nis.h).
  type, bind(c), public :: nis_result
     real(c_double) :: value, std_err, chi2_per_dof
     integer(c_int64_t) :: n_eval
     real(c_double) :: rel_var_per_eval, unweighting_efficiency, seconds
     integer(c_size_t) :: components
     real(c_double) :: pareto_k, ess
  end type nis_result

  public :: nis_integrand, nis_version, nis_create, nis_load, nis_free, nis_dim, nis_set_seed, &
       nis_integrate, nis_integrate_vector, nis_integrate_to, nis_result_stop, &
       nis_result_answered_by, nis_result_warnings, nis_result_estimates, nis_sample, &
       nis_sample_weighted, nis_unweighted, nis_save, nis_last_error_copy, &
       nis_last_callback_status, nis_last_error, nis_channel_fn, nis_multichannel_create, &
       nis_multichannel_integrate, nis_multichannel_integrate_to, nis_multichannel_stop, &
       nis_multichannel_channels, nis_multichannel_free

  abstract interface
     !> A scalar integrand: out(i) = f(x(:, i)); return 0, or non-zero to stop the integration.
     integer(c_int) function nis_integrand(x, n, dim, out, user) bind(c)
       import :: c_int, c_size_t, c_double, c_ptr
       integer(c_size_t), value :: n, dim
       real(c_double), intent(in) :: x(dim, n)
       real(c_double), intent(out) :: out(n)
       type(c_ptr), value :: user
     end function nis_integrand
     !> A channel's map (out = x(dim, n)) or density (out = g(n)) of the points in(dim, n).
     integer(c_int) function nis_channel_fn(input, n, dim, out, user) bind(c)
       import :: c_int, c_size_t, c_double, c_ptr
       integer(c_size_t), value :: n, dim
       real(c_double), intent(in) :: input(dim, n)
       real(c_double), intent(out) :: out(*)
       type(c_ptr), value :: user
     end function nis_channel_fn
  end interface

  interface
     type(c_ptr) function nis_version() bind(c)
       import :: c_ptr
     end function nis_version

     integer(c_int) function nis_create(json, integ) bind(c)
       import :: c_int, c_char, c_ptr
       character(kind=c_char), intent(in) :: json(*)
       type(c_ptr), intent(out) :: integ
     end function nis_create

     integer(c_int) function nis_load(path, integ) bind(c)
       import :: c_int, c_char, c_ptr
       character(kind=c_char), intent(in) :: path(*)
       type(c_ptr), intent(out) :: integ
     end function nis_load

     subroutine nis_free(integ) bind(c)
       import :: c_ptr
       type(c_ptr), value :: integ
     end subroutine nis_free

     integer(c_size_t) function nis_dim(integ) bind(c)
       import :: c_size_t, c_ptr
       type(c_ptr), value :: integ
     end function nis_dim

     integer(c_int) function nis_set_seed(integ, seed) bind(c)
       import :: c_int, c_int64_t, c_ptr
       type(c_ptr), value :: integ
       integer(c_int64_t), value :: seed
     end function nis_set_seed

     integer(c_int) function nis_integrate(integ, f, user, evals, result) bind(c)
       import :: c_int, c_int64_t, c_ptr, c_funptr, nis_result
       type(c_ptr), value :: integ, user
       type(c_funptr), value :: f
       integer(c_int64_t), value :: evals
       type(nis_result), intent(out) :: result
     end function nis_integrate

     integer(c_int) function nis_integrate_vector(integ, f, user, components, evals, result) &
          bind(c)
       import :: c_int, c_int64_t, c_size_t, c_ptr, c_funptr, nis_result
       type(c_ptr), value :: integ, user
       type(c_funptr), value :: f
       integer(c_size_t), value :: components
       integer(c_int64_t), value :: evals
       type(nis_result), intent(out) :: result
     end function nis_integrate_vector

     !> Until std_err <= max(abs_err, rel_err*|value|) or a limit (0: not given; max_evals 0:
     !> 10**8, max_seconds 0: none); nis_result_stop says which ended the run.
     integer(c_int) function nis_integrate_to(integ, f, user, rel_err, abs_err, max_evals, &
          max_seconds, result) bind(c)
       import :: c_int, c_int64_t, c_double, c_ptr, c_funptr, nis_result
       type(c_ptr), value :: integ, user
       type(c_funptr), value :: f
       real(c_double), value :: rel_err, abs_err
       integer(c_int64_t), value :: max_evals
       real(c_double), value :: max_seconds
       type(nis_result), intent(out) :: result
     end function nis_integrate_to

     integer(c_int) function nis_result_stop(integ) bind(c)
       import :: c_int, c_ptr
       type(c_ptr), value :: integ
     end function nis_result_stop

     integer(c_int) function nis_result_answered_by(integ) bind(c)
       import :: c_int, c_ptr
       type(c_ptr), value :: integ
     end function nis_result_answered_by

     !> The last result's warnings, one per line (as nis_last_error_copy copies a message).
     integer(c_size_t) function nis_result_warnings(integ, buffer, capacity) bind(c)
       import :: c_size_t, c_char, c_ptr
       type(c_ptr), value :: integ
       character(kind=c_char), intent(out) :: buffer(*)
       integer(c_size_t), value :: capacity
     end function nis_result_warnings

     !> A multi-channel integrator (signs: c_null_ptr for auto, or "auto"/"split"/"whole" //
     !> c_null_char passed as c_loc of a target string); free it with nis_multichannel_free.
     integer(c_int) function nis_multichannel_create(json, channels, count, signs, mc) bind(c)
       import :: c_int, c_char, c_size_t, c_ptr, nis_channel
       character(kind=c_char), intent(in) :: json(*)
       type(nis_channel), intent(in) :: channels(*)
       integer(c_size_t), value :: count
       type(c_ptr), value :: signs
       type(c_ptr), intent(out) :: mc
     end function nis_multichannel_create

     integer(c_int) function nis_multichannel_integrate(mc, f, user, evals, result) bind(c)
       import :: c_int, c_int64_t, c_ptr, c_funptr, nis_result
       type(c_ptr), value :: mc, user
       type(c_funptr), value :: f
       integer(c_int64_t), value :: evals
       type(nis_result), intent(out) :: result
     end function nis_multichannel_integrate

     !> Through the channels to a precision target (arguments as nis_integrate_to).
     integer(c_int) function nis_multichannel_integrate_to(mc, f, user, rel_err, abs_err, &
          max_evals, max_seconds, result) bind(c)
       import :: c_int, c_int64_t, c_double, c_ptr, c_funptr, nis_result
       type(c_ptr), value :: mc, user
       type(c_funptr), value :: f
       real(c_double), value :: rel_err, abs_err
       integer(c_int64_t), value :: max_evals
       real(c_double), value :: max_seconds
       type(nis_result), intent(out) :: result
     end function nis_multichannel_integrate_to

     integer(c_int) function nis_multichannel_stop(mc) bind(c)
       import :: c_int, c_ptr
       type(c_ptr), value :: mc
     end function nis_multichannel_stop

     !> weights(k), means(k), std_errs(k), evals(k) of the last result's channels.
     integer(c_int) function nis_multichannel_channels(mc, weights, means, std_errs, evals, k) &
          bind(c)
       import :: c_int, c_int64_t, c_size_t, c_double, c_ptr
       type(c_ptr), value :: mc
       real(c_double), intent(out) :: weights(*), means(*), std_errs(*)
       integer(c_int64_t), intent(out) :: evals(*)
       integer(c_size_t), value :: k
     end function nis_multichannel_channels

     subroutine nis_multichannel_free(mc) bind(c)
       import :: c_ptr
       type(c_ptr), value :: mc
     end subroutine nis_multichannel_free

     !> mean(k), std_err(k), cov(k, k) of the last result (cov is symmetric, so its layout is
     !> the same in both orders).
     integer(c_int) function nis_result_estimates(integ, mean, std_err, cov, k) bind(c)
       import :: c_int, c_size_t, c_double, c_ptr
       type(c_ptr), value :: integ
       integer(c_size_t), value :: k
       real(c_double), intent(out) :: mean(k), std_err(k), cov(k, k)
     end function nis_result_estimates

     integer(c_int) function nis_sample(integ, n, x, pdf) bind(c)
       import :: c_int, c_size_t, c_double, c_ptr
       type(c_ptr), value :: integ
       integer(c_size_t), value :: n
       real(c_double), intent(out) :: x(*), pdf(n)
     end function nis_sample

     integer(c_int) function nis_sample_weighted(integ, f, user, n, x, w) bind(c)
       import :: c_int, c_size_t, c_double, c_ptr, c_funptr
       type(c_ptr), value :: integ, user
       type(c_funptr), value :: f
       integer(c_size_t), value :: n
       real(c_double), intent(out) :: x(*), w(*)
     end function nis_sample_weighted

     integer(c_int) function nis_unweighted(integ, f, user, n, overweight, x, weights) bind(c)
       import :: c_int, c_size_t, c_double, c_ptr, c_funptr
       type(c_ptr), value :: integ, user
       type(c_funptr), value :: f
       integer(c_size_t), value :: n
       real(c_double), value :: overweight
       real(c_double), intent(out) :: x(*), weights(n)
     end function nis_unweighted

     integer(c_int) function nis_save(integ, path) bind(c)
       import :: c_int, c_char, c_ptr
       type(c_ptr), value :: integ
       character(kind=c_char), intent(in) :: path(*)
     end function nis_save

     integer(c_size_t) function nis_last_error_copy(buffer, capacity) bind(c)
       import :: c_size_t, c_char
       character(kind=c_char), intent(out) :: buffer(*)
       integer(c_size_t), value :: capacity
     end function nis_last_error_copy

     integer(c_int) function nis_last_callback_status() bind(c)
       import :: c_int
     end function nis_last_callback_status
  end interface

contains

  !> The message of the last failed call on this thread, as a Fortran string.
  function nis_last_error() result(message)
    character(len=:), allocatable :: message
    character(kind=c_char) :: buffer(1024)
    integer(c_size_t) :: length
    integer :: i
    length = min(nis_last_error_copy(buffer, int(size(buffer), c_size_t)), &
         int(size(buffer) - 1, c_size_t))
    allocate(character(len=length) :: message)
    do i = 1, int(length)
       message(i:i) = buffer(i)
    end do
  end function nis_last_error

end module nis
